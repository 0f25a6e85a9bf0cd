"""LivePreview (app/live_preview.py): the SLAM thread's offer never waits for a render, a render
answers the newest offer, pacing holds renders back, flush() renders the newest at once."""

import threading

import pytest

from app.live_preview import LivePreview


class HeldRender:
    """A render that blocks until released, recording what it rendered."""

    def __init__(self):
        self.started = threading.Event()
        self.release = threading.Event()
        self.seen = []

    def __call__(self, index):
        self.seen.append(index)
        self.started.set()
        assert self.release.wait(30)
        return f"view {index}"


def test_offer_never_waits_for_a_render_and_the_newest_offer_wins():
    render = HeldRender()
    preview = LivePreview(render, interval_s=0.0, duty=1.0)
    try:
        preview.offer(0)
        assert render.started.wait(30)          # frame 0's render is running and held
        for i in range(1, 50):                  # the SLAM thread goes on: offers return at once
            preview.offer(i)
        render.release.set()
        preview.flush(30)
        assert preview.latest() == "view 49"
        assert render.seen == [0, 49]           # frames 1-48 were dropped, not rendered late
    finally:
        render.release.set()
        preview.close()


def test_pacing_holds_renders_back_and_flush_renders_the_newest_now():
    seen = []
    first = threading.Event()

    def render(index):
        seen.append(index)
        first.set()
        return index

    preview = LivePreview(render, interval_s=3600.0)   # after a render, none for an hour...
    try:
        preview.offer(1)
        assert first.wait(30)
        preview.offer(2)
        preview.offer(3)
        assert seen == [1] and preview.renders <= 1     # ...so 2 and 3 wait
        preview.flush(30)                               # ...unless flushed (a pause, the run's end)
        assert seen == [1, 3] and preview.latest() == 3
        preview.flush(30)                               # nothing new: returns at once
        assert seen == [1, 3]
    finally:
        preview.close()


def test_a_failing_render_keeps_the_last_view_and_does_not_hang_flush():
    def render(index):
        if index == 2:
            raise RuntimeError("no map yet")
        return index

    preview = LivePreview(render, interval_s=0.0)
    try:
        preview.offer(1)
        preview.flush(30)
        preview.offer(2)
        preview.flush(30)
        assert preview.latest() == 1
    finally:
        preview.close()


def test_duty_must_be_a_share_of_one_core():
    with pytest.raises(ValueError):
        LivePreview(lambda: None, duty=0.0)
