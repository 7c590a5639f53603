"""A few seeds of the randomized sessions (tests/ur_emulator/fuzz.py): a fault drawn at
random (or none) at a random time of a random session, against the emulator, with the real
ur_rtde client. Each case must end in bounded time with every acquisition on disk, the exit
code its fault calls for, no servoJ after the fault was noticed and no script left running.
`python -m ur_emulator.fuzz` runs many (the issue's 1000) by hand; here a few seeds keep
the emulator suite within its time budget."""

from __future__ import annotations

import pytest
from ur_emulator import worker_host
from ur_emulator.fuzz import CASE_BOUND, Case, run_case
from ur_emulator.sessions import time_limit

pytest.importorskip("rtde_control")

#: link reset, emergency stop, protective stop, a freeze shorter than rtde_timeout, the
#: controller killed, Ctrl-C (Case.draw(seed).fault); the fault tests cover the rest.
SEEDS = (0, 1, 6, 7, 9, 29)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_random_session_with_a_random_fault_keeps_every_invariant(seed, tmp_path):
    case = Case.draw(seed)
    with time_limit(CASE_BOUND + 45.0):
        result = run_case(case, worker_host(200 + seed), tmp_path)
    assert result["problems"] == [], result
