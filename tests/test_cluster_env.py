"""The local cluster's workers run single-threaded pools, and the caller's environment is
left as it was (distributed applies the nanny's pre-spawn variables to the parent)."""

from __future__ import annotations

import os

import pytest

from services.cluster import THREAD_ENV, open_client


def _probe():
    import os

    from threadpoolctl import threadpool_info

    return ({v: os.environ.get(v) for v in (*THREAD_ENV, "MALLOC_TRIM_THRESHOLD_")},
            [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"])


@pytest.mark.timeout(120)
def test_workers_single_threaded_and_caller_environment_untouched(monkeypatch):
    for var in (*THREAD_ENV, "MALLOC_TRIM_THRESHOLD_"):
        monkeypatch.delenv(var, raising=False)
    with open_client(workers=1) as (client, n):
        env, blas = client.submit(_probe, pure=False).result()
    assert n == 1 and all(env[v] == "1" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"))
    assert blas and set(blas) == {1}
    # glibc's default trimming in the workers (distributed's eager 64 KiB threshold
    # cost a closed-loop run 15-20 % CPU)
    assert env["MALLOC_TRIM_THRESHOLD_"] is None
    assert all(os.environ.get(v) is None for v in THREAD_ENV)
