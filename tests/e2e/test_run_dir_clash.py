"""Runs started together without --out each get their own directory (claimed atomically, not checked then
taken later)."""

from __future__ import annotations

import pytest

import datetime as dt
import threading

from dyno.session import root as app

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


class _Frozen(dt.datetime):
    @classmethod
    def now(cls, tz=None):
        return cls(2026, 11, 26, 12, 0, 0)


def test_a_clash_on_the_same_second_takes_the_next_suffix(tmp_path, monkeypatch):
    monkeypatch.setattr(app._dt, "datetime", _Frozen)
    (tmp_path / "20261126-120000").mkdir()  # another process took this second's name first
    a = app.default_run_dir(tmp_path)
    b = app.default_run_dir(tmp_path)
    assert (a.name, b.name) == ("20261126-120000-2", "20261126-120000-3")
    assert a.is_dir() and b.is_dir()  # claimed on return: nobody else can take them


def test_eight_threads_at_once_get_eight_directories(tmp_path, monkeypatch):
    monkeypatch.setattr(app._dt, "datetime", _Frozen)
    got: list = []
    start = threading.Barrier(8)

    def one():
        start.wait()
        got.append(app.default_run_dir(tmp_path))

    threads = [threading.Thread(target=one) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(got)) == 8 and all(p.is_dir() for p in got)
