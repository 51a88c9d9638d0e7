"""The learned detector's pixel classifier: features, fit, file round trip."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import check_grad

from estimator.surround.detection import VehicleDetector
from estimator.surround.pixel_classifier import (
    BUILTIN_MODEL,
    Energies,
    PixelClassifier,
    cross_entropy,
    feature_names,
    fit_classifier,
    gather,
    level_features,
    pixel_features,
)

LAMS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)


def _rings(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) points and labels: inside the unit circle or not (not linearly separable)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (n, 2))
    return X, np.hypot(*X.T) < 1.0


def test_cross_entropy_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    Z = rng.normal(size=(40, 3))
    t = rng.random(40) < 0.4
    w = rng.uniform(0.5, 2.0, 40)
    w /= w.sum()
    hidden = 4
    theta = rng.normal(0, 0.5, hidden * 3 + 2 * hidden + 1)
    err = check_grad(
        lambda th: cross_entropy(th, Z, t, w, hidden, 1e-3)[0],
        lambda th: cross_entropy(th, Z, t, w, hidden, 1e-3)[1],
        theta,
    )
    assert err < 1e-5


def test_fit_separates_a_nonlinear_class_it_was_not_shown():
    X, y = _rings(3000, 1)
    model = fit_classifier(X, y, hidden=8, max_iter=300)
    Xt, yt = _rings(2000, 2)  # other points, drawn independently
    accuracy = np.mean((model.probability(Xt) > 0.5) == yt)
    assert accuracy > 0.95
    assert model.meta["n_samples"] == 3000


def test_sample_weights_move_the_decision():
    """Negatives weighted up (as a class sampled at a lower rate): fewer positives called."""
    X, y = _rings(3000, 3)
    plain = fit_classifier(X, y, hidden=8, max_iter=200)
    heavy = fit_classifier(X, y, np.where(y, 1.0, 20.0), hidden=8, max_iter=200)
    assert (heavy.probability(X) > 0.5).sum() < (plain.probability(X) > 0.5).sum()


def test_fit_refuses_one_class_and_bad_shapes():
    with pytest.raises(ValueError, match="both classes"):
        fit_classifier(np.zeros((10, 2)), np.zeros(10, bool))
    with pytest.raises(ValueError, match=r"\(N, F\)"):
        fit_classifier(np.zeros((10, 2)), np.zeros(9, bool))


@settings(max_examples=15, deadline=None)
@given(f=st.integers(1, 6), h=st.integers(1, 5), seed=st.integers(0, 1000))
def test_save_load_round_trip(tmp_path_factory, f, h, seed):
    rng = np.random.default_rng(seed)
    model = PixelClassifier(
        rng.normal(size=f),
        rng.uniform(0.1, 2.0, f),
        rng.normal(size=(h, f)),
        rng.normal(size=h),
        rng.normal(size=h),
        float(rng.normal()),
        {"drives": ["a", "b"], "seed": seed},
    )
    path = tmp_path_factory.mktemp("m") / "sub" / "model.npz"
    model.save(path)
    back = PixelClassifier.load(path)
    X = rng.normal(size=(20, f))
    np.testing.assert_allclose(back.probability(X), model.probability(X), rtol=1e-6)
    assert back.meta == model.meta
    assert [p.name for p in path.parent.iterdir()] == ["model.npz"]  # no temporary left


def test_load_names_the_file_it_cannot_use(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.npz"):
        PixelClassifier.load(tmp_path / "nothing.npz")
    bad = tmp_path / "bad.npz"
    np.savez(bad, mean=np.zeros(2))
    with pytest.raises(ValueError, match="bad.npz"):
        PixelClassifier.load(bad)
    with pytest.raises(ValueError, match="W1"):
        PixelClassifier(np.zeros(2), np.ones(2), np.zeros((3, 4)), np.zeros(3), np.zeros(3), 0.0)


def test_level_features_tell_which_hypothesis_explains_a_patch():
    """A patch that the car-fixed hypothesis (lambda 0) predicts exactly, elsewhere the road:
    on the patch energy[0] is below the best static energy, off it the road's is the best."""
    rng = np.random.default_rng(4)
    shape = (80, 80)
    tex = lambda: np.clip(128 + 40 * rng.normal(size=shape), 0, 255).astype(np.float32)  # noqa: E731
    warped = {lam: tex() for lam in LAMS}
    current = warped[1.0].copy()
    current[30:50, 30:50] = warped[0.0][30:50, 30:50]
    ok = np.ones(shape, bool)
    energies = Energies()
    VehicleDetector._score(current, warped, ok, 5.0, 40.0, 0.7, keep=energies)
    assert sorted(energies.E) == sorted(LAMS) and sorted(energies.S) == [0.0, 0.25, 0.5, 0.75]
    f = level_features(current, energies, K=5.0, k=40.0, sigma=0.7)
    assert len(f) == len(LAMS) + 1 + 3 + 2
    e0, e_road = f[0], f[LAMS.index(1.0)]
    assert e0[40, 40] < -1.0
    assert e_road[10, 10] == pytest.approx(0.0, abs=1e-5) and e0[10, 10] > 1.0
    planes = pixel_features(f, f, f[0], f[0], np.zeros(shape, np.float32), 7)
    assert len(planes) == len(feature_names(LAMS))
    index = np.flatnonzero(ok)[::7]
    X = gather(planes, index)
    assert X.shape == (len(index), len(planes))
    np.testing.assert_array_equal(X[:, 3], planes[3].ravel()[index])


def test_builtin_model_matches_the_detector_features():
    model = PixelClassifier.load(BUILTIN_MODEL)
    assert model.n_features == len(feature_names(LAMS))
    assert model.meta["features"] == feature_names(LAMS)
    assert model.meta["drives"]  # what it was fitted to is in the file
