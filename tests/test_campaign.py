"""``ssmpc campaign``: the spec's errors, Dask runs equal to runs made here, resuming.

The TE campaign here is 6 runs of 10 process hours (2 cases x 3 strategies, one
noise seed): the same runs are made one by one in the test process and compared
with what a local cluster of worker processes and a real ``dask scheduler`` with
two ``dask worker`` processes on loopback return.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from services.campaign.identity import plan_runs
from services.campaign.runs import execute
from services.campaign.spec import parse_spec
from services.cli import main

REPO = Path(__file__).resolve().parents[1]
METRICS = ("tripped", "trip", "time_to_grade_h", "peak_pressure_kpa", "mean_cost_usd_h",
           "final_cost_usd_h", "transition_cost_usd", "active_model_share",
           "product_variability")

# 0 -> 1 is reached within the run (the same product: at grade once the reactor level
# and temperature have followed the plan's 3 h references, 7-8 h); IDV(6) from mode 2
# can trip the plant: the comparison covers grade times and trips alike
TE_SPEC = {
    "unit": "te", "hours": 10, "noise": True, "seeds": [3],
    "strategies": ["ssmpc", "pi", "plan"],
    "cases": [
        {"name": "0-1", "start": "mode0", "legs": [{"at_h": 0.5, "grade": "mode1"}]},
        {"name": "idv6", "start": "mode2", "idvs": [{"idv": 6, "on_h": 0.2, "off_h": 2.8}]},
    ],
}


def _write(path: Path, spec: dict) -> str:
    path.write_text(json.dumps(spec))
    return str(path)


def _campaign(capsys, *args) -> tuple[int, dict | None, str]:
    code = main(["campaign", *args])
    out, err = capsys.readouterr()
    lines = out.strip().splitlines()
    doc = json.loads(lines[-1]) if "--json" in args and lines else None
    return code, doc, err


def _assert_same_metrics(a: dict, b: dict) -> None:
    for key in METRICS:
        va, vb = a[key], b[key]
        if isinstance(va, float) or isinstance(vb, float):
            assert va == pytest.approx(vb, rel=1e-12, abs=1e-9), (a["case"], a["strategy"], key)
        elif isinstance(va, dict) and key == "active_model_share":
            assert va == pytest.approx(vb, rel=1e-12), (a["case"], a["strategy"], key)
        else:
            assert va == vb, (a["case"], a["strategy"], key)


def _by_run(doc: dict) -> dict:
    return {(r["case"], r["strategy"], r["seed"]): r for r in doc["runs"]}


@pytest.fixture(scope="module")
def local_campaign(tmp_path_factory):
    """The TE campaign on a local cluster of 2 worker processes, via the command line."""
    root = tmp_path_factory.mktemp("campaign")
    spec = _write(root / "te.json", TE_SPEC)
    out = root / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "services.cli", "campaign", spec, "--out", str(out),
         "--workers", "2", "--json"], capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(REPO)}, cwd=root)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1]), out, proc.stderr


@pytest.fixture(scope="module")
def serial_rows():
    """The same runs made one by one in this process."""
    spec = parse_spec(TE_SPEC, "te")
    return {(r.case.name, r.strategy, r.seed): execute(r).row for r in plan_runs(spec)}


# -- bad specs --------------------------------------------------------------------------------
def _bad(spec_patch):
    spec = json.loads(json.dumps(TE_SPEC))
    spec_patch(spec)
    return spec


BAD_SPECS = [
    ("unit", lambda s: s.update(unit="reactor9")),
    ("cases[0].legs[0].grade", lambda s: s["cases"][0]["legs"][0].update(grade="mode9")),
    ("cases[1].start", lambda s: s["cases"][1].update(start="OPI")),
    ("cases[0].start", lambda s: s["cases"][0].update(start="mode4")),
    ("strategies[1]", lambda s: s.update(strategies=["ssmpc", "bangbang"])),
    ("cases[1].idvs[0].idv", lambda s: s["cases"][1]["idvs"][0].update(idv=21)),
    ("hours", lambda s: s.update(hours=-2)),
    ("cases[0].hours", lambda s: s["cases"][0].update(hours=0)),
    ("cases[1].idvs[0].off_h", lambda s: s["cases"][1]["idvs"][0].update(off_h=0.2)),
    ("cases[0].legs[0].at_h", lambda s: s["cases"][0]["legs"][0].update(at_h=50.0)),
    ("seeds[0]", lambda s: s.update(seeds=[-1])),
    ("cases[1].colour", lambda s: s["cases"][1].update(colour="red")),
    ("horizon", lambda s: s.update(horizon=3)),
    ("cases[0].idvs", lambda s: s.update(unit="cstr", strategies=["pi"], noise=False,
                                         cases=[{"name": "a", "start": "OPI",
                                                 "idvs": [{"idv": 1, "on_h": 0}]}])),
    ("strategies[0]", lambda s: s.update(unit="cstr", strategies=["plan"], noise=False,
                                         cases=[{"name": "a", "start": "OPI"}])),
]


@pytest.mark.parametrize("field,patch", BAD_SPECS, ids=[f for f, _ in BAD_SPECS])
def test_a_bad_spec_is_an_error_naming_the_field_and_writes_nothing(tmp_path, capsys, field,
                                                                    patch):
    spec = _write(tmp_path / "bad.json", _bad(patch))
    out = tmp_path / "out"
    code, _, err = _campaign(capsys, spec, "--out", str(out), "--json")
    assert code == 2
    assert err.startswith(f"error: {field}: "), err
    assert "Traceback" not in err
    assert not out.exists()


def test_an_unreadable_or_malformed_spec_file_is_an_error(tmp_path, capsys):
    code, _, err = _campaign(capsys, str(tmp_path / "missing.json"))
    assert code == 2 and err.startswith("error: spec: ")
    (tmp_path / "nan.json").write_text('{"unit": "te", "hours": NaN}')
    code, _, err = _campaign(capsys, str(tmp_path / "nan.json"))
    assert code == 2 and err.startswith("error: spec: ")


#: The campaign spec of the design brief, as printed there (docs/campaigns.md).
DESIGN_SPEC = {
    "unit": "te", "hours": 48, "noise": True, "seeds": [1, 2, 3],
    "strategies": ["ssmpc", "fixed", "pi", "plan", "decentralized"],
    "cases": [
        {"name": "0-2", "start": "mode0", "legs": [{"at_h": 1.0, "grade": "mode2"}]},
        {"name": "idv6@2", "start": "mode2", "idvs": [{"idv": 6, "on_h": 2.0}]},
        {"name": "0-2+idv8", "start": "mode0", "legs": [{"at_h": 1.0, "grade": "mode2"}],
         "idvs": [{"idv": 8, "on_h": 0.5, "off_h": 30.0}]}]}


def test_the_design_spec_parses():
    spec = parse_spec(DESIGN_SPEC)
    assert spec.n_runs == 3 * 5 * 3
    case = spec.cases[2]
    assert (case.hours, case.noise, case.seeds) == (48.0, True, (1, 2, 3))
    assert case.idvs[0].off_h == 30.0 and case.legs[0].grade == "mode2"


def test_a_run_identity_changes_with_what_makes_the_run_different():
    base = parse_spec(TE_SPEC, "te")
    ids = {(r.case.name, r.strategy): r.run_id for r in plan_runs(base)}
    renamed = json.loads(json.dumps(TE_SPEC))
    renamed["cases"][0]["name"] = "zero-to-one"
    assert sorted(r.run_id for r in plan_runs(parse_spec(renamed))) == sorted(ids.values())
    for patch in (lambda s: s["cases"][0]["legs"][0].update(at_h=0.6),
                  lambda s: s["cases"][0].update(hours=4),
                  lambda s: s["cases"][0].update(noise=False),
                  lambda s: s["cases"][0].update(seeds=[4]),
                  lambda s: s["cases"][0].update(idvs=[{"idv": 8, "on_h": 1.0}])):
        changed = json.loads(json.dumps(TE_SPEC))
        patch(changed)
        new = {(r.case.name, r.strategy): r.run_id for r in plan_runs(parse_spec(changed))}
        for key, rid in new.items():
            assert (rid != ids[key]) == (key[0] == "0-1"), key


def _te_run_ids_with(monkeypatch, module, name, value) -> tuple[set, set]:
    """The TE example's run identities before and with ``module.name`` set to ``value``
    (undone after; asserts the identities come back)."""
    from services.campaign import identity

    before = {r.run_id for r in plan_runs(parse_spec(TE_SPEC, "te"))}
    monkeypatch.setattr(module, name, value)
    identity._settings_json.cache_clear()
    try:
        after = {r.run_id for r in plan_runs(parse_spec(TE_SPEC, "te"))}
    finally:
        monkeypatch.undo()
        identity._settings_json.cache_clear()
    assert {r.run_id for r in plan_runs(parse_spec(TE_SPEC, "te"))} == before
    return before, after


def test_a_run_identity_changes_with_the_plant_sides_inner_loops(monkeypatch):
    """Runs made with another regulatory layer are other runs: a campaign resumed in the
    same directory after the inner loops changed makes them again."""
    import controller.units.te.loops as loops

    before, after = _te_run_ids_with(monkeypatch, loops, "INNER_LOOPS", loops.MODEL_LOOPS)
    assert before and not before & after


@pytest.mark.parametrize("module, cls, field, value", [
    ("controller.units.te.level_sag", "LevelSagSettings", "pressure_kpa", 2880.0),
    ("controller.units.te.floating_pressure", "FloatingPressureSettings", "ceiling_kpa",
     2860.0),
    ("controller.units.te.production_index", "ProductionIndexSettings", "gain", 0.6),
    ("controller.units.te.overrides", "FeedOverrideSettings", "filter_h", 0.1),
])
def test_a_run_identity_changes_with_a_guards_settings(monkeypatch, module, cls, field,
                                                        value):
    """The TE guards' own settings are part of a run: with another default of any of
    them a resumed campaign makes its runs again."""
    import dataclasses
    import importlib

    mod = importlib.import_module(module)
    changed = dataclasses.replace(getattr(mod, cls)(), **{field: value})
    before, after = _te_run_ids_with(monkeypatch, mod, cls, lambda: changed)
    assert before and not before & after


def test_a_run_identity_changes_with_the_composition_core(monkeypatch):
    import dataclasses

    import controller.units.te.control as control

    changed = dataclasses.replace(control.COMPOSITION_MPC, move_weight=1.0e5)
    before, after = _te_run_ids_with(monkeypatch, control, "COMPOSITION_MPC", changed)
    assert before and not before & after


def test_a_run_identity_changes_with_the_mpc_leg_references(monkeypatch):
    import dataclasses

    import controller.units.te.control as control

    changed = dataclasses.replace(control.LEG_REFERENCES_MPC, tau_fraction=0.5)
    before, after = _te_run_ids_with(monkeypatch, control, "LEG_REFERENCES_MPC", changed)
    assert before and not before & after


def test_a_run_identity_changes_with_the_reactor_feed_balance(monkeypatch):
    """Switched on (or retuned), the feed balance makes other runs."""
    import dataclasses

    import controller.units.te.control as control

    changed = dataclasses.replace(control.FEED_BALANCE_MPC, gain=6.0)
    before, after = _te_run_ids_with(monkeypatch, control, "FEED_BALANCE_MPC", changed)
    assert before and not before & after


# -- the campaign on Dask ---------------------------------------------------------------------
def test_local_cluster_gives_the_metrics_of_the_runs_made_one_by_one(local_campaign,
                                                                     serial_rows):
    doc, out, err = local_campaign
    assert doc["workers"] == 2
    trips = sum(r["tripped"] for r in serial_rows.values())
    assert doc["summary"] == {"runs": 6, "tripped": trips, "errors": 0, "executed": 6,
                              "skipped": 0}
    got = _by_run(doc)
    assert set(got) == set(serial_rows)
    for key, row in serial_rows.items():
        assert row["error"] is None
        _assert_same_metrics(got[key], row)
    # the comparison saw a grade reached (and its cost), not only empty metrics
    assert any(r["time_to_grade_h"] is not None for r in serial_rows.values())
    # 0 -> 1 keeps the product: at grade only once the reactor level has come from 75
    # to within 1 % of 65 % on the plan's 3 h reference (3 ln 10 = 6.9 h after the leg);
    # the MPC's own reference of it is three times faster
    leg = {key[1]: r["time_to_grade_h"] for key, r in serial_rows.items() if key[0] == "0-1"}
    assert all(leg[s] is None or leg[s] > 6.0 for s in ("pi", "plan"))
    assert leg["ssmpc"] is not None and leg["ssmpc"] < 6.0
    # the MPC strategy reports its models; the others none
    assert set(got[("0-1", "ssmpc", 3)]["active_model_share"]) == {"reinit", "mode0", "mode2",
                                                                   "mode3"}
    assert got[("0-1", "pi", 3)]["active_model_share"] == {}
    assert "6/6 runs" in err and "ETA" in err


def test_the_results_directory_holds_the_document_the_runs_and_the_report(local_campaign):
    doc, out, _ = local_campaign
    saved = json.loads((out / "results.json").read_text())
    assert saved["runs"] == doc["runs"]
    files = sorted((out / "runs").glob("*.npz"))
    assert len(files) == 6
    row = doc["runs"][0]
    with np.load(out / "runs" / f"{row['run']}.npz") as z:
        assert json.loads(str(z["row"][()]))["case"] == row["case"]
        t = z["t_h"]
        assert t.shape == (1000,) and z["xmeas"].shape == (1000, 41)  # 10 h at 36 s
        assert t[1] - t[0] == pytest.approx(0.01)
        assert float(np.max(z["xmeas"][:, 6])) == pytest.approx(row["peak_pressure_kpa"])
    png = (out / "report.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    page = (out / "report.html").read_text()
    assert 'src="report.png"' in page and page.count("<tr>") == 7
    assert len((out / "table.csv").read_text().strip().splitlines()) == 7
    assert not list(out.rglob("*.part"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster(tmp_path):
    """A ``dask scheduler`` and two ``dask worker`` processes on loopback."""
    dask = Path(sys.executable).with_name("dask")
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], env=env, cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    addr = f"tcp://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.2)
    for _ in range(2):
        procs.append(subprocess.Popen(
            [str(dask), "worker", addr, "--nworkers", "1", "--nthreads", "1",
             "--no-dashboard"], env=env, cwd=tmp_path, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))
    yield addr
    for p in reversed(procs):
        p.send_signal(signal.SIGTERM)
    for p in reversed(procs):
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def test_a_real_scheduler_and_two_workers_give_the_same_results(dask_cluster, local_campaign,
                                                                tmp_path, capsys):
    spec = _write(tmp_path / "te.json", TE_SPEC)
    code, doc, err = _campaign(capsys, spec, "--scheduler", dask_cluster, "--workers", "2",
                               "--out", str(tmp_path / "out"), "--json")
    assert code == 0, err
    assert doc["workers"] == 2 and doc["summary"]["executed"] == 6
    local = _by_run(local_campaign[0])
    for key, row in _by_run(doc).items():
        _assert_same_metrics(row, local[key])
        assert row["run"] == local[key]["run"]


def test_an_interrupted_campaign_resumes_without_redoing_finished_runs(local_campaign,
                                                                       tmp_path, capsys):
    doc, out, _ = local_campaign
    resumed = tmp_path / "out"
    shutil.copytree(out, resumed)
    # one run's file lost (as if the campaign was stopped before it finished)
    lost = doc["runs"][1]
    (resumed / "runs" / f"{lost['run']}.npz").unlink()
    kept = {p.name: p.stat().st_mtime_ns for p in (resumed / "runs").glob("*.npz")}
    spec = _write(tmp_path / "te.json", TE_SPEC)
    code, again, err = _campaign(capsys, spec, "--out", str(resumed), "--workers", "1",
                                 "--json")
    assert code == 0, err
    assert again["summary"]["executed"] == 1 and again["summary"]["skipped"] == 5
    assert "(5 already done)" in err
    for name, mtime in kept.items():
        assert (resumed / "runs" / name).stat().st_mtime_ns == mtime
    _assert_same_metrics(_by_run(again)[(lost["case"], lost["strategy"], lost["seed"])], lost)
    # everything there: nothing is run
    code, third, _ = _campaign(capsys, spec, "--out", str(resumed), "--json")
    assert code == 0 and third["summary"]["executed"] == 0 and third["summary"]["skipped"] == 6
    # a spec change gives the changed case's runs new identities: only they run
    changed = json.loads(json.dumps(TE_SPEC))
    changed["cases"][1]["idvs"][0]["off_h"] = 1.0
    code, fourth, _ = _campaign(capsys, _write(tmp_path / "te2.json", changed), "--out",
                                str(resumed), "--workers", "1", "--json")
    assert code == 0 and fourth["summary"]["executed"] == 3


def test_a_run_that_raises_is_a_row_with_its_error_and_the_campaign_goes_on(tmp_path, capsys,
                                                                            monkeypatch):
    from distributed import LocalCluster

    from services.campaign import runs

    real = runs._loop

    def broken(run, hours=None):
        if run.strategy == "plan" and hours is None:
            raise RuntimeError("solver exploded")
        return real(run, hours)

    monkeypatch.setattr(runs, "_loop", broken)
    spec = dict(TE_SPEC, strategies=["pi", "plan"], hours=1.0, noise=False,
                cases=[dict(TE_SPEC["cases"][0]), {"name": "idv6", "start": "mode2",
                                                   "idvs": [{"idv": 6, "on_h": 0.2}]}])
    path = _write(tmp_path / "s.json", spec)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        code, doc, err = _campaign(capsys, path, "--scheduler", cluster.scheduler_address,
                                   "--out", str(tmp_path / "out"), "--json")
        assert code == 1
        rows = _by_run(doc)
        assert rows[("0-1", "plan", 3)]["error"] == "RuntimeError: solver exploded"
        assert rows[("0-1", "pi", 3)]["error"] is None
        assert doc["summary"]["errors"] == 2 and "2 errors" in err
        # failed runs are not kept as finished: the next start runs them again
        monkeypatch.setattr(runs, "_loop", real)
        code, doc, _ = _campaign(capsys, path, "--scheduler", cluster.scheduler_address,
                                 "--out", str(tmp_path / "out"), "--json")
        assert code == 0 and doc["summary"]["executed"] == 2


def test_a_unit_plant_campaign_runs_its_registry_controller(tmp_path, capsys):
    spec = {"unit": "cstr", "hours": 0.004, "strategies": ["ssmpc", "pi"],
            "cases": [{"name": "I-II", "start": "OPI", "legs": [{"at_h": 0.0005,
                                                                  "grade": "OPII"}]}]}
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        code, doc, err = _campaign(capsys, _write(tmp_path / "c.json", spec), "--scheduler",
                                   cluster.scheduler_address, "--json")
    assert code == 0, err
    rows = _by_run(doc)
    ss, pi = rows[("I-II", "ssmpc", 1)], rows[("I-II", "pi", 1)]
    # 14.4 s of CSTR time at 0.05: the transition (20 s planned) is followed, not finished
    assert ss["peak_pressure_kpa"] is None and ss["mean_cost_usd_h"] is None
    assert set(ss["active_model_share"]) >= {"M1", "M2"} and pi["active_model_share"] == {}
    assert sum(ss["active_model_share"].values()) == pytest.approx(1.0)


def test_a_campaign_stopped_with_ctrl_c_keeps_its_finished_runs(tmp_path, capsys):
    spec = {"unit": "te", "hours": 20, "seeds": list(range(1, 9)), "strategies": ["plan"],
            "cases": [{"name": "0-2", "start": "mode0",
                       "legs": [{"at_h": 1.0, "grade": "mode2"}]}]}
    path = _write(tmp_path / "s.json", spec)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "services.cli", "campaign", path, "--out", str(out),
           "--workers", "1", "--json"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list(out.glob("runs/*.npz"))) < 2:
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    finished = len(list(out.glob("runs/*.npz")))
    assert f"interrupted: {finished} finished runs kept" in err
    assert 2 <= finished < 8, "the campaign ended before it was stopped: make the runs longer"
    assert not list(out.rglob("*.part"))
    saved = json.loads((out / "results.json").read_text())
    assert len(saved["runs"]) == finished
    code, doc, err = _campaign(capsys, path, "--out", str(out), "--workers", "1", "--json")
    assert code == 0, err
    assert doc["summary"]["skipped"] == finished
    assert doc["summary"]["executed"] == 8 - finished


def test_bench_campaign_reports_serial_and_workers_cases(capsys):
    code = main(["bench", "campaign", "--runs", "2", "--hours", "0.2", "--repeats", "1",
                 "--workers", "1", "--strategy", "plan", "--json"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["bench"] == "campaign"
    serial, workers, pool = doc["cases"]
    assert serial["case"] == "serial" and workers["case"] == "workers 1"
    assert pool["case"] == "pool 1"
    for c in (serial, workers, pool):
        assert c["unit"] == "runs/s" and c["n"] == 1 and c["median"] > 0
        assert c["cpu_s_per_run"] > 0 and c["cores_used"] > 0
    assert main(["bench", "campaign", "--workers", "0", "--json"]) == 2


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parent.parent / "docs"
                                         / "campaigns").glob("*.json")),
                         ids=lambda p: p.name)
def test_every_shipped_campaign_spec_is_valid(path):
    # the specs the docs tell a user to run parse as they stand (a field renamed in
    # the spec's contract would otherwise surface only when someone runs them)
    spec = parse_spec(json.loads(path.read_text()), default_name=path.stem)
    assert spec.cases and spec.strategies and spec.n_runs >= len(spec.cases)
