"""Peak memory per stage (memory.py): a stage's peak holds what it allocated, nested stages too."""

import sys

import numpy as np
import pytest

from ovrad_addon import memory

linux = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="per-stage peaks need Linux's clear_refs"
)


def touch(mib: int) -> np.ndarray:
    a = np.empty(mib << 20, np.uint8)
    a[::4096] = 1  # resident: every page written
    return a


@linux
def test_a_stage_sees_its_own_allocation_and_the_next_stage_does_not():
    peaks = memory.StagePeaks()
    with peaks.stage("big"):
        base = memory.resident_mb()
        a = touch(300)
        del a
    with peaks.stage("small"):
        b = touch(20)
        del b
    assert peaks.mb["big"] >= base + 290
    # the kernel's peak was reset: the second stage does not inherit the first one's 300 MiB
    assert peaks.mb["small"] < peaks.mb["big"] - 200


@linux
def test_an_outer_stage_keeps_the_peak_of_an_inner_one():
    peaks = memory.StagePeaks()
    with peaks.stage("outer"):
        base = memory.resident_mb()
        with peaks.stage("inner"):
            a = touch(300)
            del a
        with peaks.stage("after"):
            pass
    assert peaks.mb["inner"] >= base + 290
    assert peaks.mb["outer"] >= peaks.mb["inner"]
    assert peaks.mb["after"] < peaks.mb["inner"] - 200


def test_peak_is_known_on_this_system():
    assert memory.peak_mb() is not None and memory.peak_mb() > 0
