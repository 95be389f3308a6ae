"""TorchRL loggers for a run directory: CSV always, TensorBoard when asked for and installed."""
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
    if logger_cfg.get("tensorboard", False):
        if importlib.util.find_spec("tensorboard") is None:
            log.warning("logger.tensorboard=true but tensorboard is not installed: CSV only")
        else:
            from torchrl.record.loggers import TensorboardLogger

            loggers.append(TensorboardLogger(exp_name=exp_name, log_dir=str(run_dir)))
    return MultiLogger(loggers)
