"""Slow phases are announced on stderr; fast ones are silent; progress bars log sparingly into a
file and redraw on a terminal."""

from __future__ import annotations

import io
import time

from physdrape.progress import directory_size, progress_bar, slow_phase


def test_a_slow_phase_says_what_it_does_and_when_it_ends():
    out = io.StringIO()
    with slow_phase("building something", after=0.01, done=lambda: "cache 3 MB", stream=out):
        time.sleep(0.2)
    lines = out.getvalue().splitlines()
    assert lines[0] == "[physdrape] building something ..."
    assert lines[1].startswith("[physdrape] ... done in ") and lines[1].endswith("; cache 3 MB")


def test_a_fast_phase_is_silent():
    out = io.StringIO()
    with slow_phase("quick", after=5.0, stream=out):
        pass
    assert out.getvalue() == ""


def test_directory_size(tmp_path):
    (tmp_path / "a").write_bytes(b"x" * 2_000_000)
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "b").write_bytes(b"x" * 1_000_000)
    assert directory_size(tmp_path) == "3 MB"


def test_iteration_progress_reports_at_most_once_per_interval():
    from types import SimpleNamespace

    from physdrape.progress import iteration_progress

    now = [0.0]
    out = io.StringIO()
    report = iteration_progress("oracle polish", every=5.0, stream=out, clock=lambda: now[0])
    for k, t in enumerate([1.0, 4.9, 5.1, 6.0, 10.2]):
        now[0] = t
        report(SimpleNamespace(iteration=k, residual=0.5 / (k + 1), energy=0.25, wall=t))
    lines = out.getvalue().splitlines()
    assert lines == ["[physdrape] oracle polish: iteration 2, residual 0.167, E 0.25 J, 5 s",
                     "[physdrape] oracle polish: iteration 4, residual 0.1, E 0.25 J, 10 s"]


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _updates(stream, steps: int = 40) -> int:
    """How many times a bar wrote its line while stepping `steps` times, 20 ms apart."""
    bar = progress_bar(total=steps, desc="work", stream=stream)
    for _ in range(steps):
        time.sleep(0.02)
        bar.update(1)
    bar.close()
    return stream.getvalue().count("work:")


def test_a_bar_redraws_on_a_terminal_and_logs_sparingly_into_a_file():
    """Stepping for about a second: on a terminal the line is redrawn several times, into a file
    (not a terminal) it is written when the bar opens and closes, not in between."""
    assert _updates(_Terminal()) >= 5
    assert _updates(io.StringIO()) <= 3
