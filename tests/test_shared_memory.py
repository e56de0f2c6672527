"""A node whose Zenoh shared-memory segments cannot be made (``/dev/shm`` read-only or
full) stops at start with ``error: ...`` and exit 2 and says how to run without shared
memory, never a signal death; and a fatal signal leaves the stacks in the log.

The controller runs as a real process in a mount namespace of its own whose ``/dev/shm``
is a small tmpfs (root with ``unshare``; elsewhere the test is skipped: it would need
the machine's own /dev/shm filled).
"""

import shutil
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]


def _in_own_dev_shm(tmp_path, mount_opts: str, fill_kib: int = 0):
    script = (f"mount -t tmpfs -o {mount_opts} tmpfs /dev/shm || exit 99; "
              + (f"dd if=/dev/zero of=/dev/shm/fill bs=1k count={fill_kib} 2>/dev/null; "
                 if fill_kib else "")
              + f"exec {sys.executable} -m services.cli controller --unit cstr --state-dir "
                f"{tmp_path} --no-telemetry --duration 3")
    return subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                          capture_output=True, text=True, timeout=150)


def _skip_without_namespaces():
    if shutil.which("unshare") is None:
        pytest.skip("no unshare")
    probe = subprocess.run(["unshare", "-m", "--propagation", "private", "true"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip("no mount namespaces here (needs root)")


@pytest.mark.parametrize("opts,fill", [("ro", 0), ("size=16k", 16)],
                         ids=["read-only", "full"])
def test_no_room_for_shared_memory_is_a_clear_error(tmp_path, opts, fill):
    _skip_without_namespaces()
    proc = _in_own_dev_shm(tmp_path, opts, fill)
    assert proc.returncode != 99, "tmpfs mount failed"
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert proc.stderr.startswith("error: zenoh:") and "/dev/shm" in proc.stderr
    assert "shared_memory" in proc.stderr and "Traceback" not in proc.stderr


def test_a_fatal_signal_leaves_the_stacks_in_the_log(tmp_path):
    """SIGBUS (what touching a mapped page that cannot be backed raises) in a node
    process: its stderr names the signal and the Python stacks."""
    code = ("import os, signal, sys; from services.nodes import run; run._logging(); "
            "os.kill(os.getpid(), signal.SIGBUS)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == -7
    assert "Fatal Python error: Bus error" in proc.stderr and "File " in proc.stderr
