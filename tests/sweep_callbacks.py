"""A Hydra callback for the sweep tests: the job numbered `job` dies as a killed process would (SIGKILL)."""

from __future__ import annotations

import os
import signal
from typing import Any

from hydra.experimental.callback import Callback

__all__ = ["KillJob"]


class KillJob(Callback):
    """Kill the worker process of job number `job` once Hydra has made its folder (no Python cleanup runs)."""

    def __init__(self, job: int) -> None:
        self.job = int(job)

    def on_job_start(self, config: Any, **kwargs: Any) -> None:
        if int(config.hydra.job.num) == self.job:
            os.kill(os.getpid(), signal.SIGKILL)
