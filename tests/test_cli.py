"""The command line's own conventions: help, unknown ids, JSON on the last line."""

import json
import subprocess
import sys

from services.cli import main
from services.output import atomic_output


def test_help_lists_core_commands(capsys):
    try:
        main(["--help"])
    except SystemExit as exc:
        assert exc.code == 0
    out = capsys.readouterr().out
    for cmd in ("sim", "bench", "reproduce"):
        assert cmd in out


def test_only_ssmpc_bench_loads_the_benchmarks():
    """A command other than ``bench`` (a node, the router) starts without importing the
    benchmarks and the numerical core behind them; ``ssmpc bench --help`` lists them."""
    probe = ("import sys; from services.cli import main\n"
             "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
             "print(sorted(m for m in sys.modules if m.startswith(('services.bench.', "
             "'numba'))))")
    router = subprocess.run([sys.executable, "-c", probe, "router", "--help"],
                            capture_output=True, text=True, timeout=120)
    assert router.returncode == 0 and "--credentials" in router.stdout
    assert router.stdout.strip().splitlines()[-1] == "[]"
    bench = subprocess.run([sys.executable, "-c", probe, "bench", "--help"],
                           capture_output=True, text=True, timeout=120)
    assert bench.returncode == 0 and "adapt-switch" in bench.stdout
    assert "services.bench.qp" in bench.stdout.strip().splitlines()[-1]


def test_reproduce_unknown_id_is_a_clear_error(capsys):
    code = main(["reproduce", "R99.9", "--json"])
    assert code == 2
    err = capsys.readouterr().err
    assert "R99.9" in err and err.startswith("error:")


def test_console_script_entry_point_runs():
    proc = subprocess.run([sys.executable, "-m", "services.cli", "reproduce", "list"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_atomic_output_leaves_no_partial_file(tmp_path):
    target = tmp_path / "run.csv"
    try:
        with atomic_output(target) as fh:
            fh.write("half,")
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []
    with atomic_output(target) as fh:
        fh.write(json.dumps({"a": 1}))
    assert json.loads(target.read_text()) == {"a": 1}


def test_atomic_output_has_ordinary_permissions(tmp_path):
    import os

    umask = os.umask(0o022)
    try:
        target = tmp_path / "fig.png"
        with atomic_output(target, "wb") as fh:
            fh.write(b"x")
        assert (target.stat().st_mode & 0o777) == 0o644
    finally:
        os.umask(umask)
