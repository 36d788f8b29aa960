"""``nerfedit_plugin.timing``: stage times, and the progress reports a display listens to (Stopwatch, Span)."""

import pytest

from nerfedit_plugin.timing import Span, Stopwatch, labelled, no_progress


def test_stopwatch_times_stages_and_names_each_as_it_starts():
    started = []
    clock = Stopwatch(started.append)
    with clock.stage("a"):
        pass
    with clock.stage("b"):
        pass
    with clock.stage("a"):
        pass
    assert started == ["a", "b", "a"] and set(clock.seconds) == {"a", "b"} and clock.current is None


def test_progress_goes_to_the_listener_with_the_current_stage():
    heard = []
    clock = Stopwatch(on_progress=lambda *report: heard.append(report))
    clock.progress(1, 2, "outside every stage: dropped")
    with clock.stage("bind"):
        clock.progress(0, None, "factorising")
        with clock.stage("inner"):
            clock.progress(1, 3)
        clock.progress(2, 3, "x")  # the outer stage again
    assert heard == [("bind", 0, None, "factorising"), ("inner", 1, 3, ""), ("bind", 2, 3, "x")]
    assert clock.current is None


def test_a_stage_that_raises_is_not_recorded_and_leaves_no_current_stage():
    clock = Stopwatch(on_progress=lambda *report: None)
    with pytest.raises(ValueError), clock.stage("bad"):
        raise ValueError
    assert clock.current is None and "bad" not in clock.seconds


def test_without_a_listener_progress_is_a_no_op():
    clock = Stopwatch()
    with clock.stage("s"):
        clock.progress(1, 2, "nobody hears this")
    no_progress(1, 2, "nor this")


def test_span_reports_positions_within_its_part_of_the_bar():
    heard = []
    span = Span(lambda *r: heard.append(r), start=200, size=100, total=300, label="frame 3/3")
    span.at(0)
    span.at(150, "more than its size")  # clamped
    span.at(detail="unfolding")  # where it was
    span.end("done")
    assert heard == [
        (200, 300, "frame 3/3"),
        (300, 300, "frame 3/3 · more than its size"),
        (300, 300, "frame 3/3 · unfolding"),
        (300, 300, "frame 3/3 · done"),
    ]


def test_span_iterations_is_a_minimiser_callback_with_the_relative_decrease():
    heard = []
    callback = Span(lambda *r: heard.append(r), start=10, size=5, total=20, label="frame 2/2").iterations()
    for k, energy in enumerate([4.0, 2.0, 1.5]):
        callback(k, energy)
    assert [(done, total) for done, total, _ in heard] == [(10, 20), (11, 20), (12, 20)]
    assert heard[0][2] == "frame 2/2 · iteration 0"
    assert heard[1][2] == "frame 2/2 · iteration 1 · ΔE/E 5.0e-01" and heard[2][2].endswith("ΔE/E 2.5e-01")


def test_labelled_leads_every_detail():
    heard = []
    progress = labelled(lambda *r: heard.append(r), "bunny bind")
    progress(0, None, "factorising")
    progress(1, 2)
    assert heard == [(0, None, "bunny bind: factorising"), (1, 2, "bunny bind")]
