"""The ray backends: embree and numpy give the same answers, and embree scenes share their threads."""

import threading

import numpy as np
import pytest

from ovrad_addon.scene.rays import has_embree, make_rays


@pytest.mark.skipif(not has_embree(), reason="embreex not installed")
def test_embree_and_numpy_backends_agree_on_random_rays():
    rng = np.random.default_rng(1)
    v = rng.normal(size=(200, 3))
    t = rng.integers(0, 200, size=(80, 3))
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])]
    o = rng.normal(size=(5000, 3)) * 2
    d = rng.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, b = make_rays(v, t, "embree"), make_rays(v, t, "numpy")
    ta, ia = a.closest_hit(o, d, 4.0)
    tb, ib = b.closest_hit(o, d, 4.0)
    assert 0.05 < (ib >= 0).mean() < 0.95  # the test actually exercises hits and misses
    assert (ia == ib).mean() > 0.999  # float32 vs float64 may flip a ray grazing an edge
    same = (ia == ib) & (ia >= 0)
    np.testing.assert_allclose(ta[same], tb[same], rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(a.occluded(o, d, 4.0), ib >= 0)


def test_numpy_backend_hits_a_known_triangle_at_the_right_distance():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    r = make_rays(v, np.array([[0, 1, 2]]), "numpy")
    t, i = r.closest_hit(np.array([[0.2, 0.2, 3.0], [2.0, 2.0, 3.0]]), np.array([[0, 0, -1.0]] * 2), np.inf)
    assert i.tolist() == [0, -1]
    assert t[0] == pytest.approx(3.0)


@pytest.mark.skipif(not has_embree(), reason="embreex not installed")
def test_embree_indices_leave_no_threads_behind():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    o, d = np.array([[0.2, 0.2, 1.0]]), np.array([[0, 0, -1.0]])
    make_rays(v, np.array([[0, 1, 2]]), "embree").closest_hit(o, d, np.inf)  # the shared pool exists now
    before = threading.active_count()
    for _ in range(20):  # one index per atlas build, prepare or bake
        assert make_rays(v, np.array([[0, 1, 2]]), "embree").closest_hit(o, d, np.inf)[1].tolist() == [0]
    assert threading.active_count() == before
