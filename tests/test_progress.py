"""Progress off a terminal (metraw.progress): a job's log gets a line every interval while it works, with where
it is and the time left, and short work stays silent (errors keep their one line)."""

from __future__ import annotations

import io

import pytest

from metraw import progress
from metraw.progress import LogProgress, progress_bar


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(progress.time, "monotonic", c)
    monkeypatch.setattr(progress, "_LAST_LINE_S", [None])  # a fresh process
    return c


def test_a_line_every_interval_with_rate_and_time_left(clock):
    out = io.StringIO()
    log = LogProgress(100, "fields", unit="scenes", interval_s=20.0, stream=out)
    for _ in range(100):
        clock.t += 0.5  # 2 scenes per second: a line every 40 scenes
        log.update()
    log.close()
    lines = out.getvalue().splitlines()
    assert lines == ["fields: 40/100 (40 %) in 0m20s, 2 scenes/s, about 0m30s left",
                     "fields: 80/100 (80 %) in 0m40s, 2 scenes/s, about 0m10s left",
                     "fields: 100/100 (100 %) in 0m50s, 2 scenes/s"]


def test_loops_each_shorter_than_the_interval_still_log_every_interval(clock):
    # a fine-tuning: 18 s of fields, then three 15 s trainings; each loop alone is shorter than 20 s
    out = io.StringIO()
    for desc, n, dt in (("fields", 18, 1.0), ("train", 15, 1.0), ("train", 15, 1.0), ("train", 15, 1.0)):
        log = LogProgress(n, desc, interval_s=20.0, stream=out)
        for _ in range(n):
            clock.t += dt
            log.update()
        log.close()
    lines = out.getvalue().splitlines()
    # a line at 20 s (train 2/15), its last at 33 s, then 53 s (train 5/15 of the third)
    assert lines == ["train: 2/15 (13 %) in 0m02s, 1 it/s, about 0m13s left",
                     "train: 15/15 (100 %) in 0m15s, 1 it/s",
                     "train: 5/15 (33 %) in 0m05s, 1 it/s, about 0m10s left",
                     "train: 15/15 (100 %) in 0m15s, 1 it/s"]


def test_short_work_writes_nothing(clock):
    out = io.StringIO()
    log = LogProgress(10, "load", interval_s=20.0, stream=out)
    for _ in range(10):
        clock.t += 1.0
        log.update()
    log.close()
    assert out.getvalue() == ""


def test_a_quick_command_after_a_long_silent_one_stays_one_line(tmp_path, capsys, monkeypatch):
    """A loop of an earlier command in the same process (a test worker, a notebook) started long ago: a quick command
    run after it through ``metraw.cli.main`` counts its silence from its own start, so its error is its only line."""
    import imagecodecs
    import numpy as np

    from metraw.cli import main

    monkeypatch.setattr(progress, "_LAST_LINE_S", [None])
    LogProgress(10, "an earlier command", interval_s=20.0, stream=io.StringIO())
    progress._LAST_LINE_S[0] -= 1000.0   # ... 1000 s ago, and silent since
    for i in range(3):
        (tmp_path / f"ok{i}.png").write_bytes(imagecodecs.png_encode(np.full((8, 8, 3), 40 * i, np.uint8)))
    (tmp_path / "z_bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 30)
    rc = main(["ingest", *sorted(map(str, tmp_path.glob("*.png"))), "--out", str(tmp_path / "out.zarr")])
    lines = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("metraw ingest: error: ") and "z_bad.png" in lines[0]


def test_progress_bar_off_a_terminal_logs_lines(clock, capsys, monkeypatch):
    monkeypatch.setenv("METRAW_LOG_INTERVAL_S", "3")

    def slow(n):
        for i in range(n):
            clock.t += 1.0
            yield i

    assert list(progress_bar(slow(7), total=7, desc="emulate")) == list(range(7))  # pytest's stderr: no terminal
    err = capsys.readouterr().err.splitlines()
    assert [line.split(" in ")[0] for line in err] == ["emulate: 3/7 (43 %)", "emulate: 6/7 (86 %)",
                                                        "emulate: 7/7 (100 %)"]
    assert list(progress_bar(slow(7), total=7, desc="quiet", disable=True)) == list(range(7))
    assert capsys.readouterr().err == ""


def test_training_logs_its_steps_with_epoch_and_loss(clock, capsys, monkeypatch):
    import numpy as np
    import torch

    from metraw.segment import train
    from metraw.segment.train import TrainConfig, train_loop

    monkeypatch.setenv("METRAW_LOG_INTERVAL_S", "5")
    monkeypatch.setattr(train, "PREFETCH_BATCHES", 0)  # batches made in step, so the fake clock is the step's
    model = torch.nn.Conv2d(4, 4, 3, padding=1)
    rng = np.random.default_rng(0)

    def epoch_batches(_epoch):
        for _ in range(4):
            clock.t += 2.0  # 2 s per step: a line every 3 steps
            yield rng.normal(size=(2, 4, 8, 8)).astype(np.float32), rng.random((2, 4, 8, 8)).astype(np.float32)

    config = TrainConfig(epochs=3, batch_size=2)
    losses = train_loop(model, epoch_batches, 4, config, "cpu")
    assert len(losses) == 3
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("train: 3/12 (25 %) in 0m06s, 0.5 steps/s, about 0m18s left; epoch 1/3, 2 images per step, loss ")
    assert err[-1].startswith("train: 12/12 (100 %)") and "epoch 3/3" in err[-1]
    assert len(err) == 4  # steps 3, 6, 9, 12
