"""The hyperparameter likelihood of the point-object model (``urn_normaliser = false``):
the Gibbs weights drop the urn normaliser, and so must the frame likelihood of (alpha, d)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bnptrack.tracker.bnp.urn import frame_loglik_grid


def test_point_model_alpha_likelihood_is_the_poisson_birth_count():
    """d = 0, V = 7.5, 4 object measurements of which 2 new: -(alpha + V) + 2 log alpha
    (Poisson(alpha) births; the seated tables contribute log 1^[1] = 0)."""
    alpha = np.array([0.05, 0.2, 1.0])
    got = frame_loglik_grid(alpha, np.array([0.0]), mass=7.5, d_bar=3.0, n_object=4, n_new=2,
                            seated_popularity=np.array([1.0, 1.0, 5.5]), seated_counts=np.array([1, 1, 0]),
                            urn_normaliser=False)
    np.testing.assert_allclose(got.ravel(), -(alpha + 7.5) + 2 * np.log(alpha), rtol=1e-12)
    assert np.argmax(-alpha + 2 * np.log(alpha)) == np.argmax(got.ravel())


def test_urn_and_point_model_differ_by_the_normaliser_terms():
    """The difference is M_o log(alpha + V) - log (alpha + V)^[M_o], by hand for M_o = 3."""
    a, d, V = 0.3, 0.2, 4.0
    kw = dict(mass=V, d_bar=2.0, n_object=3, n_new=1, seated_popularity=np.array([1.0, 3.0]),
              seated_counts=np.array([1, 1]))
    urn = frame_loglik_grid(np.array([a]), np.array([d]), **kw)
    point = frame_loglik_grid(np.array([a]), np.array([d]), urn_normaliser=False, **kw)
    t = a + V
    want = 3 * math.log(t) - math.log(t * (t + 1) * (t + 2))
    assert (urn - point).item() == pytest.approx(want, rel=1e-12)
    # and the point model by hand: -(a+V) + log(a + d * d_bar) + log(1 - d) + log(3 - d)
    assert point.item() == pytest.approx(-t + math.log(a + d * 2.0) + math.log(1 - d) + math.log(3 - d), rel=1e-12)
