"""The feed's promises to the rig loop, without a browser: a full queue loses its oldest frame and never
waits; an error while building a frame is counted, never raised into the poller; ADDR:PORT parsing."""

from __future__ import annotations

import queue
import threading

import pytest

pytest.importorskip("aiohttp", reason="the web extra is not installed (pip install -e '.[web]')")

from dyno.web.feed import LiveFeed  # noqa: E402
from dyno.web.server import parse_bind  # noqa: E402

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


class _Boom:
    """A source whose values cannot be read (a half-built controller, say)."""

    class controller:  # noqa: N801
        state, aborts, points = "x", [], []

    @property
    def poller(self):
        raise RuntimeError("no poller")


def test_full_queue_drops_the_oldest_without_waiting():
    feed = LiveFeed(None, queue_size=2)

    def publish():
        for k in range(1000):  # nobody takes frames: the server is stuck
            feed.put({"k": k})

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    publisher.join(timeout=60)  # a put that waited for a reader would never return: the thread would hang
    assert not publisher.is_alive(), "put() waited for a reader"
    assert [feed.frames.get_nowait()["k"], feed.frames.get_nowait()["k"]] == [998, 999]
    with pytest.raises(queue.Empty):
        feed.frames.get_nowait()
    assert feed.dropped == 998 and feed.published == 1000


def test_an_error_building_a_frame_never_reaches_the_poller():
    feed = LiveFeed(_Boom())
    feed.on_poll([], 0.0)  # must not raise
    assert feed.errors == 1 and "no poller" in feed.last_error and feed.frames.empty()


@pytest.mark.parametrize("text, want", [(None, ("127.0.0.1", 0)), ("", ("127.0.0.1", 0)),
                                        ("0.0.0.0:8026", ("0.0.0.0", 8026)), (":9000", ("127.0.0.1", 9000)),
                                        ("[::1]:80", ("::1", 80)), ("192.168.1.5", ("192.168.1.5", 0))])
def test_parse_bind(text, want):
    assert parse_bind(text) == want


@pytest.mark.parametrize("text", ["host:port", "127.0.0.1:70000", "127.0.0.1:-1"])
def test_parse_bind_refuses(text):
    with pytest.raises(ValueError, match="ADDR:PORT"):
        parse_bind(text)
