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
