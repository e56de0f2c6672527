"""``ssmpc reproduce list``: every result with what it compares and its last verdict."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from services.reproduce import discover_studies
from services.reproduce.titles import TITLES


def _run(*argv, env):
    return subprocess.run([sys.executable, "-m", "services.cli", "reproduce", *argv],
                          capture_output=True, text=True, timeout=300, env=env)


def test_every_result_has_a_title():
    assert set(discover_studies()) <= set(TITLES)


def test_list_shows_titles_and_the_verdict_of_a_run(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}
    before = _run("list", "--json", env=env)
    assert before.returncode == 0, before.stderr
    rows = {r["id"]: r for r in json.loads(before.stdout.splitlines()[-1])["results"]}
    assert rows["R3.0"]["verdict"] is None and rows["R3.0"]["title"] == TITLES["R3.0"]
    run = _run("R3.0", "--json", env=env)
    assert run.returncode == 0, run.stderr
    verdict = json.loads(run.stdout.splitlines()[-1])["verdict"]
    text = _run("list", env=env).stdout.splitlines()
    line = next(ln for ln in text if ln.startswith("R3.0 "))
    assert verdict in line and TITLES["R3.0"] in line


def test_several_results_in_one_call_in_the_order_given(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}
    run = _run("R5.1", "r3.4", "R5.1", "--json", env=env)
    assert run.returncode == 0, run.stderr
    docs = json.loads(run.stdout.splitlines()[-1])["results"]
    assert [d["id"] for d in docs] == ["R5.1", "R3.4"]  # each once
    assert all(d["verdict"] and d["rows"] for d in docs)
    # each one's verdict is kept, as a single run's is
    rows = {r["id"]: r for r in json.loads(_run("list", "--json", env=env).stdout
                                           .splitlines()[-1])["results"]}
    assert [rows[d["id"]]["verdict"] for d in docs] == [d["verdict"] for d in docs]
    text = _run("R3.4", "R5.1", env=env).stdout.splitlines()
    assert text[0].startswith("R3.4: ") and any(ln.startswith("R5.1: ") for ln in text)


def test_an_unknown_id_among_several_runs_nothing(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}
    run = _run("R3.4", "R99.1", "R98", env=env)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.startswith("error:") and "'R99.1'" in run.stderr and "'R98'" in run.stderr
    listed = json.loads(_run("list", "--json", env=env).stdout.splitlines()[-1])["results"]
    assert next(r for r in listed if r["id"] == "R3.4")["verdict"] is None
    alone = _run("list", "R3.4", env=env)
    assert alone.returncode == 2 and "stands alone" in alone.stderr
