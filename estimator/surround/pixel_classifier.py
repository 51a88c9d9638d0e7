"""Which pixels see a vehicle: a small classifier over the motion hypotheses' evidence.

The motion score m (`estimator.surround.detection`) decides a pixel from one ratio of
windowed residual energies and a fixed threshold. What tells a vehicle apart is spread
over more than that ratio: which of all the hypotheses explains the pixel (the
energies of every static and moving one, each against the best static one), how far
the road's and each moving hypothesis' predictions differ there (S_j), how much
texture there is (the misregistration floor), the same at one pyramid level coarser,
the score around the pixel, the road range of its ray, and the local brightness and
contrast. `pixel_features` stacks them per pixel; `PixelClassifier` maps them to the
probability that the pixel sees a vehicle: standardised features, one hidden layer of
tanh units, a logistic output. Its weights are fitted to the id images of rendered
drives (`scenarios.train_pixels`) and stored as an ``.npz`` file.

The features depend on the rendered world's appearance as well as on the geometry
(brightness and contrast): a model fitted to rendered drives is the simulator's. Fit
one to labelled recordings for real footage (`scenarios.train_pixels`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from estimator.fileio import atomic_write
from estimator.surround.window import gauss_window

BUILTIN_MODEL = Path(__file__).with_name("vehicle_pixels.npz")  # fitted to `surround-train`


@dataclass
class Energies:
    """The windowed energies one level's motion score computed (`VehicleDetector._score`
    with ``keep``), each (h, w) float32: E[lambda] = <(I - I_lambda)^2> for every
    hypothesis, S[lambda] = <(I_road - I_lambda)^2> for the moving ones, G2 = <|g|^2>."""

    E: dict[float, np.ndarray] = field(default_factory=dict)
    S: dict[float, np.ndarray] = field(default_factory=dict)
    G2: np.ndarray | None = None


def level_features(
    a: np.ndarray, energies: Energies, K: float, k: float, sigma: float
) -> list[np.ndarray]:
    """One pyramid level's features, each (h, w) float32.

    a: the current frame (grey); energies: what the level's motion score computed; K
    [px]: its Gaussian window; k [grey level^2]: noise floor; sigma [px]: misregistration
    allowed on edges.

    Per hypothesis (ascending lambda): log(E_lambda + f) - log(min_static E + f), with
    f = k + <|g|^2> sigma^2 the floor; then log f; per moving hypothesis other than the
    car-fixed one: log(S_j + f) - log f; the windowed mean brightness and the local
    standard deviation [grey level / 255].
    """
    E = dict(sorted(energies.E.items()))
    e_static = np.minimum.reduce([e for lam, e in E.items() if lam >= 1.0])
    floor = k + energies.G2 * sigma * sigma
    log_floor = np.log(floor)
    out = [np.log(e + floor) - np.log(e_static + floor) for e in E.values()]
    out.append(log_floor)
    for lam, S in sorted(energies.S.items()):
        if 0.0 < lam < 1.0:
            out.append(np.log(S + floor) - log_floor)
    mean = gauss_window(a, K)
    out.append(mean / 255.0)
    out.append(np.sqrt(np.maximum(gauss_window(a * a, K) - mean * mean, 0.0)) / 255.0)
    return out


def pixel_features(
    fine: list[np.ndarray],
    coarse: list[np.ndarray],
    score: np.ndarray,
    score_coarse: np.ndarray,
    log_range: np.ndarray,
    context_px: int,
) -> list[np.ndarray]:
    """A pixel's features at the working scale: F planes (h, w) float32 (`gather` picks
    the pixels' rows).

    fine, coarse: `level_features` of the working scale and of one level coarser
    (brought to the working scale); score, score_coarse: (h, w) the motion score m at
    both (`VehicleDetector._score`); log_range: (h, w) log(1 + road range of the ray
    [m]); context_px: the size of the neighbourhood [px] whose score is summarised
    (its Gaussian mean and its maximum, at both levels).
    """
    c = int(context_px) | 1
    box = np.ones((c, c), np.uint8)
    ctx = [
        gauss_window(score, 2 * c + 1),
        gauss_window(score_coarse, 2 * c + 1),
        cv2.dilate(score, box),
        cv2.dilate(score_coarse, box),
    ]
    return [*fine, *coarse, score, score_coarse, *ctx, log_range]


def gather(planes: Sequence[np.ndarray], index: np.ndarray) -> np.ndarray:
    """(N, F) float32: the planes' values at the flat pixel indices ``index`` (N,)."""
    out = np.empty((len(planes), len(index)), np.float32)
    for row, plane in zip(out, planes, strict=True):
        np.take(plane.ravel(), index, out=row)
    return out.T


@dataclass(frozen=True)
class PixelClassifier:
    """p(vehicle | features) = sigmoid(w2 . tanh(W1 z + b1) + b2), z standardised.

    mean, scale: (F,); W1: (H, F); b1: (H,); w2: (H,); b2: scalar. meta: what the
    model was fitted to (suite, drives, frames, figures), kept in the file.
    """

    mean: np.ndarray
    scale: np.ndarray
    W1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        F, H = self.mean.shape[0], self.b1.shape[0]
        shapes = {
            "scale": (self.scale.shape, (F,)),
            "W1": (self.W1.shape, (H, F)),
            "w2": (self.w2.shape, (H,)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f"PixelClassifier: {name} has shape {got}, expected {want}")
        if not np.all(self.scale > 0):
            raise ValueError("PixelClassifier: every feature scale must be > 0")

        # the standardisation folded into the first layer, float32: W1 ((x - mean) / scale)
        # + b1 = (W1 / scale) x + (b1 - (W1 / scale) mean)
        W = self.W1 / self.scale
        object.__setattr__(self, "_W_in", np.ascontiguousarray(W.T, np.float32))  # (F, H)
        object.__setattr__(self, "_b_in", (self.b1 - W @ self.mean).astype(np.float32))
        object.__setattr__(self, "_w_out", self.w2.astype(np.float32))

    @property
    def n_features(self) -> int:
        return int(self.mean.shape[0])

    def logit(self, X: np.ndarray) -> np.ndarray:
        """(N,) log-odds of (N, F) features."""
        hidden = np.asarray(X, np.float32) @ self._W_in
        hidden += self._b_in
        np.tanh(hidden, out=hidden)
        return hidden @ self._w_out + np.float32(self.b2)

    def probability(self, X: np.ndarray) -> np.ndarray:
        """(N,) p(vehicle) of (N, F) features."""
        return 0.5 * (1.0 + np.tanh(0.5 * self.logit(X)))  # the logistic, without overflow

    def save(self, path: str | Path) -> None:
        """Write the model to ``path`` (.npz) atomically."""
        atomic_write(
            Path(path),
            lambda tmp: np.savez(
                tmp,
                mean=self.mean,
                scale=self.scale,
                W1=self.W1,
                b1=self.b1,
                w2=self.w2,
                b2=np.array(self.b2),
                meta=np.array(json.dumps(self.meta)),
            ),
        )

    @classmethod
    def load(cls, path: str | Path) -> PixelClassifier:
        """Read a model written by `save`; a clear error for a missing or bad file."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"pixel classifier {path}: no such file")
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(
                    z["mean"],
                    z["scale"],
                    z["W1"],
                    z["b1"],
                    z["w2"],
                    float(z["b2"]),
                    json.loads(str(z["meta"])),
                )
        except (KeyError, ValueError, OSError) as e:
            raise ValueError(f"pixel classifier {path}: not a model file ({e})") from e


def _unpack(theta: np.ndarray, hidden: int, F: int):
    """(W1 (H, F), b1 (H,), w2 (H,), b2) of the flat parameter vector."""
    n1 = hidden * F
    W1 = theta[:n1].reshape(hidden, F)
    return W1, theta[n1 : n1 + hidden], theta[n1 + hidden : n1 + 2 * hidden], theta[-1]


def cross_entropy(
    theta: np.ndarray, Z: np.ndarray, t: np.ndarray, w: np.ndarray, hidden: int, l2: float
) -> tuple[float, np.ndarray]:
    """(loss, its gradient (P,)) of the flat parameters theta (`_unpack`) on standardised
    features Z (N, F), labels t (N,) and weights w (N,) summing to 1: the weighted
    cross-entropy of sigmoid(w2 . tanh(W1 z + b1) + b2) plus l2 times the squared weights."""
    W1, b1, w2, b2 = _unpack(theta, hidden, Z.shape[1])
    t = np.asarray(t, np.float64)
    A = np.tanh(Z @ W1.T + b1)
    s = A @ w2 + b2
    ce = np.logaddexp(0.0, s) - t * s  # -log sigmoid(s) for t = 1, -log(1 - sigmoid(s)) for 0
    f = float(w @ ce) + l2 * float(W1.ravel() @ W1.ravel() + w2 @ w2)
    ds = w * (0.5 * (1.0 + np.tanh(0.5 * s)) - t)  # d ce / d s, weighted (tanh: no overflow)
    dA = np.outer(ds, w2) * (1.0 - A * A)
    grad = np.concatenate(
        [(dA.T @ Z + 2 * l2 * W1).ravel(), dA.sum(axis=0), A.T @ ds + 2 * l2 * w2, [ds.sum()]]
    )
    return f, grad


def fit_classifier(
    X: np.ndarray,
    y: np.ndarray,
    weight: np.ndarray | None = None,
    hidden: int = 24,
    l2: float = 1e-4,
    max_iter: int = 400,
    seed: int = 0,
    meta: dict | None = None,
) -> PixelClassifier:
    """Fit `PixelClassifier` to (N, F) features and (N,) bool labels by L-BFGS on the
    weighted mean cross-entropy plus l2 times the squared weights (scipy).

    weight: (N,) per-sample weights (e.g. the inverse of a class's sampling rate).
    """
    from scipy.optimize import minimize

    X = np.asarray(X, np.float64)
    t = np.asarray(y, np.float64)
    if X.ndim != 2 or len(X) != len(t) or len(X) == 0:
        raise ValueError(f"fit_classifier: X (N, F) and y (N,) needed, got {X.shape}, {t.shape}")
    if not (0 < t.mean() < 1):
        raise ValueError("fit_classifier: both classes must be present in y")
    w = np.ones(len(t)) if weight is None else np.asarray(weight, np.float64)
    w = w / w.sum()
    mean = X.mean(axis=0)
    scale = X.std(axis=0)
    scale[scale < 1e-6] = 1.0
    Z = (X - mean) / scale
    N, F = Z.shape
    rng = np.random.default_rng(seed)
    theta0 = np.concatenate(
        [
            rng.normal(0, 1 / np.sqrt(F), hidden * F),
            np.zeros(hidden),
            rng.normal(0, 1 / np.sqrt(hidden), hidden),
            [0.0],
        ]
    )
    res = minimize(
        cross_entropy,
        theta0,
        args=(Z, t, w, hidden, l2),
        jac=True,
        method="L-BFGS-B",
        options={"maxiter": max_iter},
    )
    W1, b1, w2, b2 = _unpack(res.x, hidden, F)
    info = dict(meta or {})
    info.update(n_samples=int(N), loss=float(res.fun), iterations=int(res.nit))
    return PixelClassifier(mean, scale, W1, b1, w2, float(b2), info)


def feature_names(lambdas: Sequence[float]) -> list[str]:
    """The names of `pixel_features`' planes for hypotheses ``lambdas``."""
    lams = sorted(lambdas)
    one = (
        [f"energy[{lam:g}]" for lam in lams]
        + ["log_floor"]
        + [f"separation[{lam:g}]" for lam in lams if 0.0 < lam < 1.0]
        + ["brightness", "contrast"]
    )
    return (
        [f"fine.{n}" for n in one]
        + [f"coarse.{n}" for n in one]
        + ["score", "score_coarse", "score_mean", "score_coarse_mean"]
        + ["score_max", "score_coarse_max", "log_road_range"]
    )
