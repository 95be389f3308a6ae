"""Several TorchRL loggers as one (built by :func:`kddrl_trl.factories.make_logger`), and the trimming of a
resumed run's logs."""

from __future__ import annotations

from pathlib import Path


class MultiLogger:
    """Fans ``log_scalar`` out to several TorchRL loggers."""

    def __init__(self, loggers):
        self.loggers = list(loggers)

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        for logger in self.loggers:
            logger.log_scalar(name, float(value), step=step)


def trim_logs(run_dir: Path, last_step: int, eval_last_step: int, exp_name: str = "logs") -> None:
    """Before a resumed run logs again: drop the ``train/`` and ``time/`` rows after ``last_step`` (episodes
    logged after the checkpoint, which the resumed run replays), the periodic ``eval/`` rows after
    ``eval_last_step`` (logged at the number of episodes trained; the last evaluation the checkpoint records: one
    that finished after it is run again) and any ``test/`` file (the final evaluation restarts). TorchRL's CSV
    logger appends, so without this those rows would appear twice."""
    folder = Path(run_dir) / exp_name / "scalars"
    if not folder.is_dir():
        return
    from .atomic_files import write_text_atomic

    for path in folder.rglob("*.csv"):
        rel = path.relative_to(folder).as_posix()
        if rel.startswith("test"):
            path.unlink()
            continue
        last = eval_last_step if rel.startswith("eval") else last_step
        rows = [line for line in path.read_text().splitlines() if line and int(float(line.split(",")[0])) <= last]
        write_text_atomic(path, "".join(r + "\n" for r in rows))
