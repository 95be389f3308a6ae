"""The example's training curves (studies/reuse/curves.py): read from its progress bar's lines, a run not finished
named and left out, a finished run's log without a progress line refused."""

from pathlib import Path

import pytest

from studies.reuse import curves


def _log(path: Path, points: list[tuple[int, int]], total: int, result=True) -> None:
    """A log as the example's bar writes it (carriage returns between updates), and its result beside it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    bar = [f"training episodes:  0%| | {n}/{total} [00:01<00:02, 1.00ep/s, collisions_last_50={p}%]" for n, p in points]
    path.write_text("warm-up line\n" + "\r".join(bar) + "\nsandbox, seed 0: {...}\n")
    if result:
        path.with_suffix(".json").write_text("{}")


def test_the_value_at_an_episode_is_the_last_printed_at_the_first_count_reaching_it(tmp_path):
    log = tmp_path / "a.log"
    _log(log, [(0, 0), (48, 90), (51, 80), (51, 70), (99, 60), (100, 50), (100, 40)], 100)
    assert curves.read_curve(log, every=50) == {50: 70.0, 100: 40.0}


def test_unfinished_runs_are_named_and_left_out_and_arms_follow_their_folders(tmp_path, capsys):
    _log(tmp_path / "example_safe" / "transforms__0.log", [(50, 20)], 50)
    _log(tmp_path / "example_safe" / "no-transforms__3.log", [(50, 30)], 50)
    _log(tmp_path / "example_default" / "transforms__1.log", [(50, 10)], 50)
    _log(tmp_path / "example_default" / "no-transforms__1.log", [(20, 10)], 50, result=False)
    got = curves.read_curves(tmp_path, every=50)
    assert got == {"h": {0: {50: 20.0}}, "i": {3: {50: 30.0}}, "n": {1: {50: 10.0}}}
    assert "no-transforms__1.log: no result beside it" in capsys.readouterr().err


def test_a_finished_log_without_progress_or_short_of_its_total_is_refused(tmp_path):
    (tmp_path / "empty.log").write_text("Traceback ...\n")
    with pytest.raises(ValueError, match="empty.log: no progress line"):
        curves.read_curve(tmp_path / "empty.log", every=50)
    _log(tmp_path / "short.log", [(20, 10), (60, 5)], 150)
    with pytest.raises(ValueError, match="short.log: the bar never reached episode 100 of 150"):
        curves.read_curve(tmp_path / "short.log", every=50)


def test_markdown_caps_the_columns_and_writes_both_files(tmp_path):
    for seed in (0, 1):
        _log(
            tmp_path / "src" / "example_default" / f"transforms__{seed}.log",
            [(n, seed) for n in range(50, 1001, 50)],
            1000,
        )
    curves.main([str(tmp_path / "src"), "--out", str(tmp_path / "out")])
    md = (tmp_path / "out" / "curves.md").read_text()
    assert "| seed | 100 | 200 | 300 | 400 | 500 | 600 | 700 | 800 | 900 | 1000 |" in md
    assert "| mean | 0.5 | 0.5 |" in md
    assert '"1000": 1.0' in (tmp_path / "out" / "curves.json").read_text()


def test_compressed_logs_read_as_plain_ones_and_a_second_log_of_a_run_is_refused(tmp_path):
    import lzma

    _log(tmp_path / "example_safe" / "transforms__0.log", [(50, 20), (100, 10)], 100)
    plain = curves.read_curves(tmp_path, every=50)
    packed = tmp_path / "example_safe" / "transforms__0.log.xz"
    packed.write_bytes(lzma.compress((tmp_path / "example_safe" / "transforms__0.log").read_bytes()))
    with pytest.raises(ValueError, match="a second log of example_safe/transforms__0"):
        curves.read_curves(tmp_path, every=50)
    (tmp_path / "example_safe" / "transforms__0.log").unlink()
    assert curves.read_curves(tmp_path, every=50) == plain == {"h": {0: {50: 20.0, 100: 10.0}}}
