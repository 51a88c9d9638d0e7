"""The off-road map (`OffroadMapper.map`): the pixels of a frame that the fitted road
motion does not explain, kept out of the next frame pair's points (paper section 4 keeps
its points on the road; the road ring of an omni image is crowded with guard rails,
posts, vehicles and the ego car's roof).

Two tests mark a textured pixel of frame B, after the pair (A, B) is fitted:

- the residual test: A warped onto B with the fitted road motion leaves a residual that
  the noise and a small normal motion do not explain (vehicles, the ego body, anything
  whose motion is far from the road's);
- the plane-parallax test (`_parallax_marks`): a plane above the road (``lambda K0``)
  explains the pixel's neighbourhood better than the road does (rails, posts, kerbs:
  their parallax over a pair is a pixel or two, within the noise pixel by pixel).

A slow pair compares B with an older frame for the parallax test (the chain of recent
well-fitted pairs, `baseline`), and the parallax marks are averaged over frames per cell
along the road motion (`_raised_cells`): kerbs pass the test in about half their pixels
per frame, the road in a tenth.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.homography import V_SLICE, homography
from estimator.egomotion.levels import Level
from estimator.egomotion.pyramid import (
    Frame,
    gaussian_kernel,
    in_level,
    roi_gradients,
    sample_points,
    valid_at,
)
from estimator.egomotion.roi_strip import RoiStrip, roi_strip, strip_blur_image

Motion = list[tuple[np.ndarray, float]]  # frame pairs (x (9,), dt [s]), oldest first


def composed_homography(motion: Motion, K: np.ndarray) -> np.ndarray:
    """(3, 3) homography of the plane K over consecutive pairs (at least one): each pair's
    eq. 3, the latest applied last (plane-induced homographies of one plane compose); one
    pair's is its own."""
    x0, dt0 = motion[0]
    H = homography(x0, K, dt0)
    for x, dt in motion[1:]:
        H = homography(x, K, dt) @ H
    return H


class OffroadMapper:
    """Off-road maps of the frames of one camera (`map`).

    Holds what depends on the camera (the blur strips of the parallax test, the evidence
    cells) and what carries over from frame to frame: the raised-structure evidence of
    the last frame mapped forward (``raised``, (H_r, W_r) float32 or None; ``raised_of``,
    that frame), which the next pair carries on only if its first frame is that one, and
    the chain of the last well-fitted consecutive pairs (``chain``: first frame (`_slim`),
    x, dt, gain, oldest first; ``chain_end``: the last one's second frame), the baseline
    of slow pairs.
    """

    def __init__(
        self,
        camera: CameraModel,
        K0: np.ndarray,
        levels: list[Level],
        cfg: DirectConfig,
        mask_lvl: int,
    ) -> None:
        self.camera, self.K0, self.levels, self.cfg = camera, K0, levels, cfg
        self.mask_lvl = mask_lvl
        # (4, 1) fractions of a marked pixel's motion that `_smeared_marks` also marks
        self._smear_steps = np.linspace(-cfg.mask_smear, cfg.mask_smear, 5)[[0, 1, 3, 4], None]
        self._parallax_strips: dict[tuple[int, int], RoiStrip] = {}  # `_parallax_strip`
        self._cell_maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # `_cells`
        self.chain: list[tuple[Frame, np.ndarray, float, float]] = []
        self.chain_end: Frame | None = None
        self.raised: np.ndarray | None = None
        self.raised_of: Frame | None = None

    def map(
        self,
        A: Frame,
        B: Frame,
        x: np.ndarray,
        dt: float,
        gain: float,
        s2: float,
        backward: bool = False,
        residuals: bool = True,
    ) -> np.ndarray:
        """(H_m, W_m) uint8: pixels of frame B that the estimated road motion does not explain.

        x (9,): the pair's fitted state, dt [s] its time step, gain its brightness gain
        B -> A, s² its noise scale. At the mask level, frame A is warped onto B's ROI pixels
        with x (H⁻¹, as in `DirectEstimator.compensate`); a pixel is marked where its
        residual |r| exceeds what a normal motion of ``mask_motion_px`` (level px) and the
        noise explain: ``|r| > mask_motion_px |g| + sqrt(snoop_threshold s²)
        sigma_intensity`` (s² >= 1: the fit's noise level).
        Residuals below that are the data snooping's business (eq. 20-21); marking them
        would drop, frame after frame, the points that disagree with the estimate.
        Textured structures above the road (rails, posts, vehicles, the ego body) leave
        such residuals; the mask keeps their neighbourhood out of the next frame pair's
        points, where B is frame A (`select_points`): their pixels would blend, through
        the pyramid's smoothing, motion that is not the road's into road points. Motion
        blur spreads a structure along its image motion: marks are also smeared along
        +/- ``mask_smear`` of the pixel's motion. Structure above the road whose residual
        is within the noise pixel by pixel is caught by the plane-parallax test
        (`_parallax_marks`, ``parallax_lambdas``).

        backward: the pair's frames in reverse (B is then the pair's first frame, A its
        second): the map of the first frame from the pair's own fit (``own_map``).
        residuals: False: the plane-parallax marks alone (``first_map_residuals``).
        """
        cfg, lvl = self.cfg, self.mask_lvl
        hm, wm = self.levels[lvl].shape
        pair = [(x, dt)]
        pair_gain = 1.0 / gain if backward else gain  # A's brightness over B's
        tex, idx, g, w_a, ok, b_val, r_road = self._road_residuals(
            A, B, pair, lvl, backward, pair_gain
        )
        textured = tex, idx  # B's textured pixels at the mask level
        noise = math.sqrt(cfg.snoop_threshold * min(max(s2, 1.0), 100.0)) * cfg.sigma_intensity
        if residuals:
            bad = ok & (np.abs(r_road) > cfg.mask_motion_px * g + noise)
            out = self._smeared_marks(idx[bad], w_a[bad], (hm, wm))
        else:
            out = np.zeros((hm, wm), np.uint8)
        if cfg.parallax_lambdas:
            plvl = self._parallax_lvl()
            A_p, motion, gain_p = (
                (A, pair, pair_gain) if backward else self.baseline(A, x, dt, gain)
            )
            w_road = w_a  # where the road puts B's textured pixels in A_p
            if plvl != lvl:  # the windowed test at a coarser level (cheaper), marks upsampled
                tex, idx, g, w_a, ok, b_val, r_road = self._road_residuals(
                    A_p, B, motion, plvl, backward, gain_p
                )
                w_road = w_a
            elif A_p is not A:
                # against an older frame: B's same textured pixels (gathered once); the marks'
                # smear stays the pair's own motion (w_a)
                _, _, _, w_road, ok, _, r_road = self._road_residuals(
                    A_p, B, motion, plvl, backward, gain_p, (tex, idx, g, b_val)
                )
            par = self._parallax_marks(
                A_p, B, motion, plvl, tex, idx, w_road, b_val, r_road, ok, noise, backward, gain_p
            )
            marks = self._smeared_marks(idx[par], w_a[par], self.levels[plvl].shape)
            if plvl != lvl:
                marks = cv2.resize(marks, (wm, hm), interpolation=cv2.INTER_NEAREST)
            if cfg.raised_memory > 0 and not backward:
                # A's evidence, if A was the last frame mapped forward
                raised = self.raised if self.raised_of is A else None
                marks |= self._raised_cells(*textured, x, dt, marks, raised)
                self.raised_of = B
            out |= marks
        return out

    def remember(self, A: Frame, B: Frame, x: np.ndarray, dt: float, gain: float) -> None:
        """Add the well-fitted pair (A, B) (state x (9,), dt [s], brightness gain B -> A) to
        the chain of the plane-parallax baseline (``parallax_baseline_frames`` - 1 kept;
        none without ``parallax_baseline_m``)."""
        if self.cfg.parallax_baseline_m <= 0:
            return
        keep = self.cfg.parallax_baseline_frames - 1
        entry = (self._slim(A), x.copy(), dt, gain)
        self.chain = (self.chain_to(A) + [entry])[-keep:] if keep else []
        self.chain_end = B

    def forget(self) -> None:
        """Drop the chain (a failed fit breaks the consecutive pairs)."""
        self.chain, self.chain_end = [], None

    def chain_to(self, A: Frame) -> list[tuple[Frame, np.ndarray, float, float]]:
        """``chain`` if its last pair ends at frame A (the pairs are consecutive), else []."""
        return self.chain if self.chain_end is A else []

    def baseline(
        self, A: Frame, x: np.ndarray, dt: float, gain: float
    ) -> tuple[Frame, Motion, float]:
        """(frame, motion, gain) of the plane-parallax test of the pair (A, B) with state x
        (9,) and brightness gain B -> A: A itself, the pair's ``[(x, dt)]`` and its gain
        unless the pair travels less than ``parallax_baseline_m``; then the frame of the
        fewest earlier well-fitted consecutive pairs (`chain_to`) that reach it, or all of
        them: the pairs' (x, dt) oldest first, this pair's x last, and the product of their
        brightness gains."""
        cfg = self.cfg
        travel = float(np.linalg.norm(x[V_SLICE])) * dt
        chain = self.chain_to(A)
        if cfg.parallax_baseline_m <= 0 or not chain or travel >= cfg.parallax_baseline_m:
            return A, [(x, dt)], gain
        n = 0  # earlier pairs taken
        while n < len(chain) and travel < cfg.parallax_baseline_m:
            n += 1
            travel += float(np.linalg.norm(chain[-n][1][V_SLICE])) * chain[-n][2]
        pairs = chain[-n:]
        motion = [(xp, d) for _, xp, d, _ in pairs] + [(x.copy(), dt)]
        return pairs[0][0], motion, float(np.prod([g for *_, g in pairs])) * gain

    def _road_residuals(
        self,
        A: Frame,
        B: Frame,
        motion: Motion,
        lvl: int,
        backward: bool,
        gain: float,
        textured: tuple[np.ndarray, ...] | None = None,
    ) -> tuple[np.ndarray, ...]:
        """Frame A warped onto B's textured ROI pixels at level lvl with the road's motion
        (`_plane_pixels`); gain: A's brightness over B's;
        textured: (tex, idx, g, b_val) of an earlier call for B at this level (only A and
        the motion differ), else gathered here.

        Returns tex (N,) indices into the level's ROI candidates, idx (N,) their pixel
        indices, g (N,) B's gradient magnitude there, w_a (N, 2) where the road puts them in
        A [level px], ok (N,) usable, b_val (N,) B's brightness, r_road (N,) A - gain B.
        Only textured pixels of B can be points of the next pair (and a residual there says
        what B shows there is not the road); flat ones are left to the dilation.
        """
        cfg, level = self.cfg, self.levels[lvl]
        s = float(level.scale)
        if textured is None:
            g, _ = roi_gradients(B, level, lvl)
            tex = np.flatnonzero(g > cfg.grad_threshold)
            idx, g = level.roi_idx[tex], g[tex].astype(np.float64)
            b_val = B.stacks[lvl][0].ravel()[idx].astype(np.float64)
        else:
            tex, idx, g, b_val = textured
        rays = np.take(level.roi_rays32, tex, 0)
        P_a, w_a = self._plane_pixels(rays, self.K0, motion, backward, s)
        ok = valid_at(level.valid_b, w_a, in_level(w_a, P_a, self.K0, level.shape))
        a_val = sample_points(A.stacks[lvl][:1], w_a)[:, 0].astype(np.float64)
        return tex, idx, g, w_a, ok, b_val, a_val - gain * b_val

    def _parallax_marks(
        self,
        A: Frame,
        B: Frame,
        motion: Motion,
        lvl: int,
        tex: np.ndarray,
        idx: np.ndarray,
        w_road: np.ndarray,
        b_val: np.ndarray,
        r_road: np.ndarray,
        ok: np.ndarray,
        noise: float,
        backward: bool,
        gain: float,
    ) -> np.ndarray:
        """(len(tex),) bool: textured pixels of B that a plane above the road explains better.

        From `map`, per textured ROI pixel of B at level lvl: w_road (N, 2) where the road
        hypothesis finds it in A [level px], b_val (N,) its brightness in B, r_road (N,) the
        road's residual, ok (N,) usable; gain: A's brightness over B's.

        Plane + parallax: a static point at height z moves in the image like the plane
        ``K = lambda K0`` with ``lambda = h / (h - z)`` (eq. 3-4 with the plane moved up).
        For each ``parallax_lambdas`` hypothesis, A is warped onto B's textured ROI pixels
        and the Gaussian-windowed residual energy compared with the road's (lambda = 1):
        a pixel is marked where a raised plane leaves less than ``parallax_ratio`` of it
        and the road's energy is above the noise. Guard-rails, posts and kerbs far from
        the car move only a pixel or two more than the road there: each pixel's residual
        alone is within the noise, the comparison over a window is not.

        The residuals are sampled at B's gradient maxima (with ``nms``: a quarter of the
        textured pixels, where the next pair's points come from) and the windowed
        energies read at every textured pixel. A sample where a hypothesis moves the
        pixel less than ``parallax_min_px`` farther than the road does (low speed, near
        the focus of expansion: the two cannot be told apart) keeps the road's residual.
        """
        cfg = self.cfg
        level = self.levels[lvl]
        s = float(level.scale)
        _, lmax = roi_gradients(B, level, lvl)
        smp = np.flatnonzero(ok & lmax[tex] if lmax is not None else ok)
        rays = np.take(level.roi_rays32, tex[smp], 0)
        r2_road, w_road, b_val = np.square(r_road[smp]), np.take(w_road, smp, 0), b_val[smp]

        # The Gaussian window is truncated at 3 sigma (as OpenCV does for 8-bit images; 4
        # for float ones): 0.3 % of its weight, 2/3 of the taps. The images are zero outside
        # the ROI and read inside it: the blurs run on the ROI's pixels and a kernel's reach
        # around them (`roi_strip`): the same sums as on the whole level, on the omni
        # camera's ring ~0.36 of the pixels.
        half = math.ceil(3 * cfg.parallax_window_px)
        strip = self._parallax_strip(lvl, half)
        put, get = strip.copies[:, tex[smp]], strip.core[tex]
        window = gaussian_kernel(cfg.parallax_window_px, 2 * half + 1)
        canvas = np.zeros(strip.size + 1, np.float32)  # every blur sets the same pixels

        def blurred(values: np.ndarray) -> np.ndarray:  # (strip.size,), read once at the end
            return strip_blur_image(strip, put, values, window, canvas)

        # The windowed energies are blur(r²) / blur(1) over the samples; the blur is linear,
        # so "e_l < ratio e_road" is "blur(r²_l - ratio r²_road) < 0", and the road's energy
        # above the noise level s² sigma² is "blur(r²_road - noise² / thr) > 0": one blur
        # per hypothesis and one for the noise, none for the normalisation.
        loud = blurred(r2_road - noise**2 / cfg.snoop_threshold) > 0
        better = np.zeros(strip.size, bool)
        # every hypothesis's warp and samples at once: (L, n) per plane lambda
        n_lam = len(cfg.parallax_lambdas)
        Ks = [lam * self.K0 for lam in cfg.parallax_lambdas]
        P_l, w_l = self._planes_pixels(rays, Ks, motion, backward, s)
        apart = np.sum(np.square(w_l - w_road), axis=2) > cfg.parallax_min_px**2
        use = in_level(w_l.reshape(-1, 2), P_l.reshape(-1, 3), self.K0, level.shape)
        use = use.reshape(n_lam, -1) & apart
        a_l = sample_points(A.stacks[lvl][:1], w_l.reshape(-1, 2))[:, 0].astype(np.float64)
        for i, a_i in enumerate(a_l.reshape(n_lam, -1)):
            r2 = np.where(use[i], np.square(a_i - gain * b_val), r2_road)
            better |= blurred(r2 - cfg.parallax_ratio * r2_road) < 0
        return (better & loud)[get] & ok

    def _raised_cells(
        self,
        tex: np.ndarray,
        idx: np.ndarray,
        x: np.ndarray,
        dt: float,
        marks: np.ndarray,
        raised: np.ndarray | None,
    ) -> np.ndarray:
        """(H_m, W_m) uint8: B's textured pixels (tex (N,): indices into the mask level's ROI,
        idx (N,) their pixels, from `_road_residuals`) in cells of level ``raised_level`` that the
        plane-parallax test has marked in at least ``raised_share`` of their textured pixels,
        on average over the recent frames; stores B's evidence (H_r, W_r) float32 for the
        next pair.

        The average of frame A (raised, None: none) is carried to B along the road motion
        (bilinear, at each ROI cell's position in A; a cell new to the view starts at 0) and
        updated where B's cell has texture: ``e = m e_A + (1 - m) share_B``, m =
        ``raised_memory``. A static structure keeps its cells; a moving vehicle's marks
        are carried beside it and fade (the residual test marks it frame by frame).
        """
        cfg, lvl = self.cfg, self.mask_lvl
        rl = min(max(cfg.raised_level, lvl), cfg.levels - 1)
        level = self.levels[rl]
        hr, wr = level.shape
        cell_of, cell_px = self._cells(lvl, rl)
        # the shares per cell: means over the cell's mask-level pixels
        cell = cell_of[tex]
        n_tex = np.bincount(cell, minlength=hr * wr).astype(np.float32) / cell_px
        marked = cell[marks.ravel()[idx].view(bool)]  # marks are 0 / 1
        n_mark = np.bincount(marked, minlength=hr * wr).astype(np.float32) / cell_px
        carried = np.zeros(hr * wr, np.float32)
        if raised is not None:
            pair = [(x, dt)]
            P_a, w_a = self._plane_pixels(
                level.roi_rays32, self.K0, pair, False, float(level.scale)
            )
            ok = in_level(w_a, P_a, self.K0, level.shape)
            carried[level.roi_idx[ok]] = sample_points((raised,), w_a[ok])[:, 0]
        seen = n_tex > 0.05  # a cell with some texture updates its average
        share = n_mark / np.maximum(n_tex, 1e-6)
        m = np.float32(cfg.raised_memory)
        ev = np.where(seen, m * carried + (1 - m) * share, carried).astype(np.float32)
        self.raised = ev.reshape(hr, wr)
        out = np.zeros(marks.size, np.uint8)
        out[idx[(ev >= cfg.raised_share)[cell]]] = 1
        return out.reshape(marks.shape)

    def _smeared_marks(
        self, idx: np.ndarray, w_a: np.ndarray, shape: tuple[int, int]
    ) -> np.ndarray:
        """(H, W) uint8 map of the pixels idx (M,) of a level of that shape, each also
        marked along +/- ``mask_smear`` of its image motion (from w_a (M, 2) in the other
        frame): motion blur smears a structure along its image motion."""
        hm, wm = shape
        out = np.zeros(hm * wm, np.uint8)
        out[idx] = 1
        if self.cfg.mask_smear > 0 and len(idx):
            vb, ub = np.divmod(idx, wm)
            t = self._smear_steps
            u = np.rint(ub + t * (ub - w_a[:, 0])).astype(np.intp)  # (4, M): t != 0 (idx is set)
            v = np.rint(vb + t * (vb - w_a[:, 1])).astype(np.intp)
            inb = (u >= 0) & (u < wm) & (v >= 0) & (v < hm)
            out[v[inb] * wm + u[inb]] = 1
        return out.reshape(hm, wm)

    def _plane_pixels(
        self, rays32: np.ndarray, K: np.ndarray, motion: Motion, backward: bool, s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where the plane K under the motion (frame pairs (x, dt), oldest first: the pair's
        own ``[(x̂, dt)]``, or those from an older frame, `baseline`) puts rays32
        (N, 3) float32 of the frame being marked in the other frame (H⁻¹: second frame to
        first; H when ``backward``): P (N, 3) and its level pixels (N, 2), in float32 (the
        dense off-road map: ~5x faster projections, ~1e-4 px)."""
        P, w = self._planes_pixels(rays32, [K], motion, backward, s)
        return P[0], w[0]

    def _planes_pixels(
        self,
        rays32: np.ndarray,
        Ks: list[np.ndarray],
        motion: Motion,
        backward: bool,
        s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """`_plane_pixels` for several planes Ks at once: P (L, N, 3) and level pixels (L, N,
        2). The same values: the homographies one by one (`composed_homography`), their inverses,
        products and the projection batched (numpy runs the same LAPACK / BLAS call per
        plane; the projection is row by row)."""
        Hs = np.stack([composed_homography(motion, K) for K in Ks])
        Ms = Hs if backward else np.linalg.inv(Hs)
        P = np.asarray(rays32, np.float32) @ np.ascontiguousarray(Ms.transpose(0, 2, 1), np.float32)
        w = self.camera.project(P.reshape(-1, 3), np.float32) / np.float32(s)
        return P, w.reshape(len(Ks), -1, 2)

    def _parallax_strip(self, lvl: int, reach: int) -> RoiStrip:
        """The level's ROI packed for blurs of that reach (`roi_strip`), where
        `_parallax_marks` blurs. Computed once per level and reach."""
        key = (lvl, reach)
        if key not in self._parallax_strips:
            level = self.levels[lvl]
            self._parallax_strips[key] = roi_strip(level.roi_idx, level.shape, reach)
        return self._parallax_strips[key]

    def _cells(self, lvl: int, rl: int) -> tuple[np.ndarray, np.ndarray]:
        """(M,) flat index at level rl of the cell of each ROI pixel of level lvl (the block of
        2^(rl - lvl) x 2^(rl - lvl) pixels above it; the last row and column of cells take
        what a level of odd size leaves over) and (H_rl * W_rl,) float32 the number of level
        lvl pixels of each cell. Computed once per pair of levels."""
        key = (lvl, rl)
        if key not in self._cell_maps:
            (h, w), (hr, wr) = self.levels[lvl].shape, self.levels[rl].shape
            f = 2 ** (rl - lvl)
            rows = np.minimum(np.arange(h) // f, hr - 1)
            cols = np.minimum(np.arange(w) // f, wr - 1)
            cell = (rows[:, None] * wr + cols[None, :]).ravel()
            px = np.maximum(np.bincount(cell, minlength=hr * wr), 1).astype(np.float32)
            self._cell_maps[key] = cell[self.levels[lvl].roi_idx], px
        return self._cell_maps[key]

    def _slim(self, frame: Frame) -> Frame:
        """The frame with only what the plane-parallax test reads of an older frame: its image
        at the parallax level (~1.6 MB at 640 px instead of the pyramid's ~10 MB)."""
        plvl = self._parallax_lvl()
        stacks = [st[:1] if lvl == plvl else () for lvl, st in enumerate(frame.stacks)]
        return Frame(frame.t_s, stacks, [], [], np.empty(0, np.uint8), frame.reason)

    def _parallax_lvl(self) -> int:
        """Pyramid level of the plane-parallax test (``parallax_level``; None: the mask's)."""
        cfg = self.cfg
        return (
            self.mask_lvl if cfg.parallax_level is None else min(cfg.parallax_level, cfg.levels - 1)
        )
