"""The gaze a frame takes: the tracker's sample of the frame's time."""

from jaxadapt.viewer._simulation import Simulation


def test_a_sample_holds_for_its_hold_and_frames_take_the_one_of_their_time():
    """:meth:`Simulation.look`: a frame takes the newest sample at or before
    its time (one that came late, out of order, included), none once it is
    older than its ``hold``; a pointer's sample holds until the next."""
    sim = Simulation(session=None, publish=None)
    sim.look((1.0, 1.0), "a", at=10.0, hold=0.1)
    sim.look((3.0, 3.0), "c", at=10.2, hold=0.1)
    sim.look((2.0, 2.0), "b", at=10.1, hold=0.1)  # (came last)
    with sim.cond:
        taken = [sim.gaze_at(t)[1] for t in (9.9, 10.0, 10.05, 10.1, 10.15, 10.21, 10.31)]
    assert taken == [None, "a", "a", "b", "b", "c", None]
    sim.look((4.0, 4.0), "pointer", at=11.0)
    with sim.cond:
        assert sim.gaze_at(1e6) == ((4.0, 4.0), "pointer")
