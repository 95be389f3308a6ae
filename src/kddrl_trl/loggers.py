"""TorchRL loggers for a run directory: CSV always, TensorBoard when installed (``tensorboard: auto``) or asked."""
from __future__ import annotations

import importlib.util
import logging
from pathlib import Path
from typing import Any, Mapping

from torchrl.record.loggers import CSVLogger

log = logging.getLogger(__name__)


class MultiLogger:
    """Fans ``log_scalar`` out to several TorchRL loggers."""

    def __init__(self, loggers):
        self.loggers = list(loggers)

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        for logger in self.loggers:
            logger.log_scalar(name, float(value), step=step)

    def log_hparams(self, cfg) -> None:
        for logger in self.loggers:
            logger.log_hparams(cfg)


def make_logger(logger_cfg: Mapping[str, Any], run_dir: Path, exp_name: str = "logs") -> MultiLogger:
    loggers = []
    if logger_cfg.get("csv", True):
        loggers.append(CSVLogger(exp_name=exp_name, log_dir=str(run_dir)))
    tb = logger_cfg.get("tensorboard", "auto")
    installed = importlib.util.find_spec("tensorboard") is not None
    if str(tb).lower() == "auto":
        tb = installed
    if tb:
        if not installed:
            log.warning("logger.tensorboard=true but tensorboard is not installed: CSV only")
        else:
            from torchrl.record.loggers import TensorboardLogger

            loggers.append(TensorboardLogger(exp_name=exp_name, log_dir=str(run_dir)))
    return MultiLogger(loggers)


def trim_logs(run_dir: Path, last_step: int, exp_name: str = "logs") -> None:
    """Before a resumed run logs again: drop the ``train/`` and ``time/`` rows after ``last_step`` (episodes
    logged after the checkpoint, which the resumed run replays) and any ``eval/`` file (evaluation restarts).
    TorchRL's CSV logger appends, so without this those rows would appear twice."""
    folder = Path(run_dir) / exp_name / "scalars"
    if not folder.is_dir():
        return
    from .io import write_text_atomic

    for path in folder.rglob("*.csv"):
        rel = path.relative_to(folder).as_posix()
        if rel.startswith("eval"):
            path.unlink()
            continue
        rows = [line for line in path.read_text().splitlines() if line and int(float(line.split(",")[0])) <= last_step]
        write_text_atomic(path, "".join(r + "\n" for r in rows))
