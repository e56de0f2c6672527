"""A short description of the machine a benchmark ran on, and its load."""

from __future__ import annotations

import os
import platform


def machine_description() -> str:
    """CPU model, core count, memory and Python version as one line."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = ""
    try:
        with open("/proc/meminfo") as fh:
            kb = int(fh.readline().split()[1])
            mem = f", {kb / 1024**2:.0f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    return (f"{cpu}, {os.cpu_count()} cores{mem}, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}")


def cpu_idle_settings(root: str = "/sys") -> dict:
    """How the CPUs idle, as far as the kernel tells: it changes loop latencies.

    Returns ``{"governor", "driver", "guest_halt_poll_ns"}``; a value the kernel does not
    expose is None. In a KVM guest with the ``haltpoll`` governor, ``guest_halt_poll_ns``
    is how long an idle vCPU polls before it halts (0: it halts at once and every wake-up
    goes through the host; see ``docs/realtime.md``).
    """

    def read(path: str) -> str | None:
        try:
            with open(os.path.join(root, path)) as fh:
                return fh.read().strip() or None
        except OSError:
            return None

    poll = read("module/haltpoll/parameters/guest_halt_poll_ns")
    return {"governor": read("devices/system/cpu/cpuidle/current_governor"),
            "driver": read("devices/system/cpu/cpuidle/current_driver"),
            "guest_halt_poll_ns": int(poll) if poll is not None and poll.isdigit() else None}


def load_average() -> list[float] | None:
    """The 1-, 5- and 15-minute load averages (runnable tasks; on this 2-core machine
    shared with other work a benchmark's tail follows them), or None where the
    platform has none."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        return None
