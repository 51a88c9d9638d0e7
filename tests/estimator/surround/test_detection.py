"""Section 5 detection: compensation maps, motion hypotheses, the motion score."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.egomotion.compensation import FrameCompensator
from estimator.egomotion.homography import homography, make_state
from estimator.geometry import skew
from estimator.surround.detection import (
    DetectorConfig,
    VehicleDetector,
    _warp_window,
    hypothesis_homography,
    normalized_difference,
)

DT = 1.0 / 15.0  # [s]
X_HIGHWAY = make_state([0.0, -25.0, 0.0], [0.004, -0.003, 0.002], [0.003, -0.004, 0.0])


def _exact_maps(cam, H, scale):
    """Where each pixel of the image at ``scale`` was before H, by projecting every ray."""
    W, Hh = -(-cam.width // scale), -(-cam.height // scale)
    v, u = np.mgrid[0:Hh, 0:W].astype(float)
    w = np.stack([(u + 0.5) * scale - 0.5, (v + 0.5) * scale - 0.5], axis=-1).reshape(-1, 2)
    P = cam.unproject(w)
    q = cam.project(P @ np.linalg.inv(H).T)
    return ((q + 0.5) / scale - 0.5).reshape(Hh, W, 2)


@pytest.mark.parametrize(
    ("preset", "scale", "tol_px"),
    [
        ("omni-near", 1, 0.05),
        ("omni-near", 2, 0.1),
        ("omni-far", 2, 0.1),
        ("rectilinear-rear-left", 1, 0.3),
    ],
)
def test_coarse_maps_match_exact_projection(preset, scale, tol_px):
    """The grid-interpolated maps (with the exact ring near the horizon) stay within
    tol_px (p99, pixels of that scale) of projecting every ray, on the road pixels
    whose source is in the image."""
    cam, mount = load_camera(preset)
    comp = FrameCompensator(cam, mount)
    H = homography(X_HIGHWAY, mount.K0, DT)
    mx, my = comp.maps_h(H, scale)
    ref = _exact_maps(cam, H, scale)
    road = comp.road_mask(scale)
    inside = (ref[..., 0] > 1) & (ref[..., 1] > 1)
    inside &= (ref[..., 0] < mx.shape[1] - 2) & (ref[..., 1] < mx.shape[0] - 2)
    sel = road & inside
    err = np.hypot(mx - ref[..., 0], my - ref[..., 1])[sel]
    assert sel.sum() > 1000
    assert np.percentile(err, 99) < tol_px


def test_warp_compat_api_and_road_mask():
    cam, mount = load_camera("omni-near")
    comp = FrameCompensator(cam, mount)
    img = np.random.default_rng(0).uniform(0, 255, (cam.height, cam.width)).astype(np.float32)
    out, ok = comp.warp(img, X_HIGHWAY, DT)
    assert out.shape == img.shape and ok.dtype == bool
    assert not ok[~comp.road].any()  # only road rays are compensated
    # identity motion: the warp returns the image
    out0, ok0 = comp.warp(img, np.zeros(9), DT)
    assert (
        np.abs(out0 - img)[ok0 & (cv2.erode(ok0.astype(np.uint8), np.ones((3, 3))) > 0)].max()
        < 1e-3
    )


def test_hypothesis_homography_road_and_static_heights():
    """lambda = 1 is the road homography; a static point at height z moves like
    lambda = h / (h - z); lambda = 0 keeps a point fixed to the car (vibration only)."""
    cam, mount = load_camera("omni-near")
    K0 = mount.K0
    n = K0 / np.linalg.norm(K0)
    h = mount.height_m
    x = make_state([0.0, -25.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert np.allclose(hypothesis_homography(x, K0, n, DT, 1.0), homography(x, K0, DT))
    # a static point at height z, 12 m ahead-left (camera: X right, Y back, Z down)
    for z in (0.0, 0.5, 1.2):
        P_a = np.array([-4.0, -12.0, h - z])
        P_b = P_a - np.asarray(x[:3]) * DT  # the camera moved by V dt; no rotation
        lam = h / (h - z)
        Hl = hypothesis_homography(x, K0, n, DT, lam)
        q = Hl @ P_a
        w_pred, w_true = cam.project(q[None]), cam.project(P_b[None])
        assert np.linalg.norm(w_pred - w_true) < 1e-6
    # lambda = 0: only the vibration part of W (the car's yaw, about n, is removed)
    xw = make_state([0.0, -25.0, 0.0], [0.02, -0.01, 0.3], [0.0, 0.0, 0.0])
    H0 = hypothesis_homography(xw, K0, n, DT, 0.0)
    W_vib = np.array([0.02, -0.01, 0.0])  # n = +Z for the omni mount
    assert np.allclose(H0, np.eye(3) - skew(W_vib) * DT, atol=1e-12)


def _textured(shape, seed, blob_px=8):
    rng = np.random.default_rng(seed)
    small = (shape[0] // blob_px, shape[1] // blob_px)
    img = rng.uniform(0, 255, small).astype(np.float32)
    return cv2.resize(img, shape[::-1], interpolation=cv2.INTER_CUBIC)


def test_score_separates_a_comoving_patch_from_the_road():
    """Earlier frame: texture. Current frame: the texture moved like the road, except a
    patch that stayed where it was (a vehicle driving at the ego car's speed). The
    score is high on the patch and below the threshold on the road."""
    cam, mount = load_camera("omni-near")
    cfg = DetectorConfig()
    det = VehicleDetector(cam, mount, cfg)
    comp, s = det.comp, cfg.scale
    early = _textured((cam.height // s, cam.width // s), 1)
    x = X_HIGHWAY
    n = comp.n
    warped = {}
    for lam in (0.0, 1.0):  # the two basic hypotheses: fixed to the car, on the road
        warped[lam], _ = comp.warp_h(early, hypothesis_homography(x, mount.K0, n, DT, lam), s)
    current = warped[1.0].copy()
    ok = det.road_s & det.valid_s
    ys, xs = np.nonzero(ok)
    # a patch on the road region to the left, where the road moves ~10 px per frame
    v0, u0 = 150, 25
    patch = np.zeros_like(ok)
    patch[v0 : v0 + 14, u0 : u0 + 24] = True
    patch &= ok
    assert patch.sum() > 150
    current[patch] = warped[0.0][patch]
    m = det._score(
        current, warped, ok, cfg.window_px / s, cfg.energy_k, cfg.registration_sigma_px / s
    )
    inner = cv2.erode(patch.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    road = ok & ~(cv2.dilate(patch.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0)
    assert np.median(m[inner]) > cfg.score_threshold
    assert np.mean(m[road] > cfg.score_threshold) < 0.002


def test_score_finds_an_overtaken_patch_and_not_a_raised_static_one():
    """A patch moving like lambda = 0.6 (a vehicle the ego car overtakes, between two
    moving hypotheses) scores above the threshold with the pairwise score; one scored
    against the fixed-to-the-car hypothesis alone would not (m ~ 1 - 2 lambda* < 0).
    A patch moving like a static point 0.7 m up (lambda 1.5) stays below it."""
    cam, mount = load_camera("omni-near")
    cfg = DetectorConfig()
    det = VehicleDetector(cam, mount, cfg)
    comp, s = det.comp, cfg.scale
    early = _textured((cam.height // s, cam.width // s), 2)
    x, n = X_HIGHWAY, comp.n

    def warp(lam: float) -> np.ndarray:
        return comp.warp_h(early, hypothesis_homography(x, mount.K0, n, DT, lam), s)[0]

    warped = {lam: warp(lam) for lam in cfg.moving_lambdas + cfg.static_lambdas}
    current = warped[1.0].copy()
    ok = det.road_s & det.valid_s
    patches = {}
    for lam, (v0, u0) in ((0.6, (150, 25)), (1.5, (40, 150))):
        patch = np.zeros_like(ok)
        patch[v0 : v0 + 14, u0 : u0 + 24] = True
        patch &= ok
        assert patch.sum() > 150
        current[patch] = warp(lam)[patch]
        patches[lam] = cv2.erode(patch.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    args = (ok, cfg.window_px / s, cfg.energy_k, cfg.registration_sigma_px / s)
    m = det._score(current, warped, *args)
    assert np.median(m[patches[0.6]]) > cfg.score_threshold
    assert np.median(m[patches[1.5]]) < 0.0
    only_fixed = {lam: w for lam, w in warped.items() if lam == 0.0 or lam >= 1.0}
    assert np.median(det._score(current, only_fixed, *args)[patches[0.6]]) < cfg.score_threshold


@pytest.mark.parametrize(("delta", "counts"), [(8.9, False), (20.0, True)])
def test_an_in_between_hypothesis_counts_only_where_it_differs_from_the_road(delta, counts):
    """Flat images (no gradient: the floor is k). The current frame is the road's
    prediction + delta, hypothesis 0.75's is the road's + delta / 2: it explains the pixel
    better than the road, but where it differs from the road by less than the floor
    (S_j = delta^2 / 4 < k) it must not make the pixel move."""
    k = 40.0
    road = np.full((40, 40), 100.0, np.float32)
    warped = {0.0: road + 100.0, 0.75: road + delta / 2, 1.0: road, 1.5: road - 50.0}
    ok = np.ones(road.shape, bool)
    m = VehicleDetector._score(road + delta, warped, ok, 5.0, k, 1.0)
    assert (delta / 2) ** 2 < k or counts
    assert np.all(m > 0.5) if counts else np.all(m < 0.0)


def test_normalized_difference_is_zero_for_identical_frames():
    img = _textured((64, 64), 2)
    nd = normalized_difference(img, img, 50.0, 7)
    assert np.abs(nd).max() < 1e-6


def test_bad_config():
    with pytest.raises(ValueError):
        DetectorConfig(static_lambdas=(1.5, 2.0))
    with pytest.raises(ValueError):
        DetectorConfig(moving_lambdas=(0.0, 1.2))
    with pytest.raises(ValueError):
        DetectorConfig(scale=3)


def test_analysed_area_margins_differ_at_rim_and_hole():
    """The outer rim loses border_margin_px, the car-body hole only inner_margin_px."""
    yy, xx = np.mgrid[0:101, 0:101]
    r = np.hypot(xx - 50, yy - 50)
    valid = (r >= 20) & (r <= 45)  # annulus: hole 20 px, rim 45 px
    cfg = DetectorConfig(border_margin_px=8, inner_margin_px=2)
    area = VehicleDetector._analysed_area(valid, cfg)
    row = area[50, 50:]  # along +x from the centre
    inside = np.flatnonzero(row)
    assert inside.min() in (22, 23)  # hole edge 20 px + 2 px
    assert inside.max() in (36, 37)  # rim 45 px - 8 px
    assert not area[~valid].any()


def test_blob_without_tall_part_is_not_a_candidate():
    """A plan blob is a vehicle candidate only through a part that reaches
    min_height_m (`_tall_parts`): low structure alone (guard-rail posts closed into a
    strip) gives none; the same blob with a tall part gives one, at its tall part."""
    cam, mount = load_camera("omni-near")
    det = VehicleDetector(cam, mount, DetectorConfig())
    size = det.plan.size
    plan = np.zeros((size, size), np.uint8)
    # a block 12-40 m ahead, 3-5 m to the left (road x fwd, y left): tall enough
    c0, r0 = det.plan.to_pixel([[40.0, 5.0]])[0].astype(int)
    c1, r1 = det.plan.to_pixel([[12.0, 3.0]])[0].astype(int)
    plan[r0 : r1 + 1, c0 : c1 + 1] = 255
    assert det._blobs(plan, np.zeros_like(plan)) == []
    (cand,) = det._blobs(plan, plan)
    assert 11.0 < cand.x_m < 13.0 and 2.5 < cand.y_m < 5.5
    assert not cand.hidden


def test_body_mask_shows_the_road_up_to_the_body_and_hides_what_meets_it():
    """With the body's silhouette in place of the 75-deg cone (`with_body_mask`), the
    analysed area reaches the body, and a blob is hidden when its nearest point sees a
    pixel next to the body (the vehicle goes on behind it), not by its range."""
    cam, mount = load_camera("omni-near")
    nadir_deg = np.degrees(np.arccos(np.clip(cam.pixel_rays()[..., 2], -1.0, 1.0)))
    body = nadir_deg < 60.0  # the road is seen from h tan(60 deg) = 3.4 m
    cone = VehicleDetector(cam, mount, DetectorConfig())
    det = VehicleDetector(cam.with_body_mask(body), mount, DetectorConfig())
    ring = (nadir_deg > 62.0) & (nadir_deg < 73.0)  # road 3.7-6.4 m away
    assert det.analysed_area[ring].mean() > 0.99 and not cone.analysed_area[ring].any()
    assert not (det.analysed_area & body).any()

    def nearest_at(d, r0_m):  # a tall block 1 m wide, from r0_m to 30 m at bearing -60 deg
        plan = np.zeros((d.plan.size,) * 2, np.uint8)
        b = np.radians(-60.0)
        for r in np.arange(r0_m, 30.0, 0.1):
            for w in np.arange(-0.5, 0.51, 0.1):
                xy = [r * np.cos(b) - w * np.sin(b), r * np.sin(b) + w * np.cos(b)]
                c, rr = np.round(d.plan.to_pixel([xy])[0]).astype(int)
                plan[rr, c] = 255
        u, v = np.round(d.plan.map_x).astype(int), np.round(d.plan.map_y).astype(int)
        seen = (u >= 0) & d.analysed_area[v.clip(0, cam.height - 1), u.clip(0, cam.width - 1)]
        plan[~seen] = 0  # what the analysed area shows of it
        (cand,) = d._blobs(plan, plan)
        return cand

    assert nearest_at(det, 3.0).hidden  # reaches the body: its ground point is hidden
    far = nearest_at(det, 5.0)  # inside the cone's 7.3 m, but seen from the road
    assert not far.hidden and abs(np.hypot(far.x_m, far.y_m) - 5.0) < 0.3
    hid = nearest_at(cone, 5.0)  # the cone hides its ground point: seen from ~7.3 m
    assert hid.hidden and np.hypot(hid.x_m, hid.y_m) < 7.3


def test_paper_method_finds_what_the_road_homography_does_not_explain():
    """Section 5 as written: eq. 22 on the road-compensated pair, thresholded. A patch that
    stayed where it was (a vehicle at the ego car's speed) is a candidate near it; the
    same pair without the patch gives none; an unknown method is refused."""
    cam, mount = load_camera("omni-near")
    cfg = DetectorConfig(method="paper")
    det = VehicleDetector(cam, mount, cfg)
    comp, s = det.comp, cfg.scale
    early = _textured((cam.height // s, cam.width // s), 1)
    road, _ = comp.warp_h(early, hypothesis_homography(X_HIGHWAY, mount.K0, comp.n, DT, 1.0), s)
    still, _ = comp.warp_h(early, hypothesis_homography(X_HIGHWAY, mount.K0, comp.n, DT, 0.0), s)
    ok = det.road_s & det.valid_s
    patch = np.zeros_like(ok)
    patch[150:180, 20:50] = True
    patch &= ok
    current = road.copy()
    current[patch] = still[patch]
    found = det.detect(current, early, [(X_HIGHWAY, DT)])
    assert found.candidates
    v, u = np.nonzero(patch)
    centre_px = np.array([u.mean() + 0.5, v.mean() + 0.5]) * s - 0.5
    nearest = min(np.hypot(*(np.array(c.pixel) - centre_px)) for c in found.candidates)
    assert nearest < 30.0 * s  # [px] full resolution
    assert not det.detect(road, early, [(X_HIGHWAY, DT)]).candidates
    with pytest.raises(ValueError, match="method"):
        DetectorConfig(method="nearest")


def _box_silhouette(cam, mount, centre_xy, size_m=(4.7, 1.9), z_m=(0.15, 1.5)):
    """(H, W) bool: pixels whose ray meets an axis-aligned box standing on the road
    (centre (x fwd, y left) [m] in the ego road frame), by the slab method."""
    rays = cam.pixel_rays().reshape(-1, 3).astype(float) @ np.asarray(mount.R_car_cam).T
    o = np.asarray(mount.position_m, float)
    c = np.r_[np.asarray(centre_xy, float) + o[:2], 0.5 * sum(z_m)]
    half = np.r_[0.5 * np.asarray(size_m), 0.5 * (z_m[1] - z_m[0])]
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (c - half - o) / rays
        t1 = (c + half - o) / rays
    near = np.nanmax(np.minimum(t0, t1), axis=1)
    far = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = (far >= near) & (far > 0)
    return hit.reshape(cam.height, cam.width) & cam.valid_mask()


def test_given_vehicle_mask_replaces_the_motion_test():
    """A true vehicle mask (the silhouette of a car-sized box 12 m ahead, 4 m left) on
    frames without any motion: the detection lies at the box's point nearest the
    camera (the obstacle map of a perfect segmentation); an empty mask finds nothing."""
    cam, mount = load_camera("omni-near")
    det = VehicleDetector(cam, mount)
    s = det.cfg.scale
    full = _textured((cam.height, cam.width), 3).astype(np.float32)
    small = cv2.pyrDown(full)
    mask = _box_silhouette(cam, mount, (12.0, 4.0))
    assert mask.sum() > 200
    steps = [(X_HIGHWAY, DT)] * det.cfg.baseline_frames
    found = det.detect(small, small, steps, full, full, vehicle_mask=mask)
    assert len(found.candidates) == 1
    (c,) = found.candidates
    nearest = np.array([12.0 - 2.35, 4.0 - 0.95])
    assert np.hypot(c.x_m - nearest[0], c.y_m - nearest[1]) < 0.5  # [m]
    assert found.motion_mask.shape == (cam.height, cam.width) and s in (1, 2)
    empty = det.detect(small, small, steps, full, full, vehicle_mask=np.zeros_like(mask))
    assert not empty.candidates


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_extent_matches_a_cell_by_cell_count(seed):
    """Each blob's nearest and farthest plan distance and the first (flat order) of its
    nearest cells, against a loop over its cells; distances on a 0.2-m grid, so that
    ties occur; also with the cells' flat indices given."""
    from types import SimpleNamespace

    rng = np.random.default_rng(seed)
    S = 90
    blobs = (cv2.GaussianBlur(rng.random((S, S)), (0, 0), 3) > 0.52).astype(np.uint8)
    n, labels = cv2.connectedComponents(blobs, connectivity=8)
    yy, xx = np.mgrid[0:S, 0:S]
    dist = np.round(np.hypot(yy - S / 2, xx - S / 2) * 0.2, 1)
    fake = SimpleNamespace(_plan_dist=dist)
    got = VehicleDetector._label_extent(fake, labels, n)
    given = VehicleDetector._label_extent(fake, labels, n, np.flatnonzero(labels))
    assert n > 5
    for g in range(1, n):
        cells = np.flatnonzero(labels.ravel() == g)
        d = dist.ravel()[cells]
        assert got[0][g] == d.min() and got[1][g] == d.max()
        assert got[2][g] == cells[np.argmax(d == d.min())]
    assert np.isinf(got[0][0]) and got[2][0] == -1  # label 0 (background) has no cells
    for a, b in zip(got, given, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_boxes_match_scipy_find_objects(seed):
    """Each label's bounding box from its cells' flat indices, against scipy's
    `find_objects` on the label image (labels without cells: zeros)."""
    from scipy import ndimage

    from estimator.surround.detection import _label_boxes

    rng = np.random.default_rng(seed)
    S = 90
    blobs = (cv2.GaussianBlur(rng.random((S, S + 7)), (0, 0), 3) > 0.52).astype(np.uint8)
    n, labels = cv2.connectedComponents(blobs, connectivity=8)
    gone = rng.integers(1, n)  # a label whose cells are all left out
    cells = np.flatnonzero(labels)
    cells = cells[labels.ravel()[cells] != gone]
    boxes = _label_boxes(cells, labels.ravel()[cells], n + 2, labels.shape[1])
    assert n > 5 and boxes.shape == (n + 2, 4)
    for g, sl in enumerate(ndimage.find_objects(labels), start=1):
        want = (sl[1].start, sl[0].start, sl[1].stop - sl[1].start, sl[0].stop - sl[0].start)
        assert tuple(boxes[g]) == ((0, 0, 0, 0) if g == gone else want)
    assert not boxes[0].any() and not boxes[n:].any()


def test_road_veto_keeps_an_edge_that_moved_and_drops_road_the_road_explains():
    """The refinement's road veto (`_road_explained`): against the frame a step back,
    compensated with the road's map at the working scale (as `detect` makes it), a current
    frame that is that frame moved like the road is explained everywhere but at its edges'
    interpolation residue; a patch that stayed where it was (a vehicle's edge, moving with
    the car) is not."""
    cam, mount = load_camera("omni-near")
    cfg = DetectorConfig()
    det = VehicleDetector(cam, mount, cfg)
    comp, s = det.comp, cfg.scale
    middle = _textured((cam.height, cam.width), 3, blob_px=6)
    H1 = hypothesis_homography(X_HIGHWAY, mount.K0, comp.n, DT, 1.0)
    current, _ = comp.warp_h(middle, H1, 1)  # the exact full-resolution road warp
    r0, r1, c0, c1 = 270, 340, 30, 130  # left of the car, where the road moves ~20 px
    patch = np.zeros(current.shape, bool)
    patch[295:315, 60:100] = True
    current[patch] = middle[patch]
    a = current[r0:r1, c0:c1].astype(np.float32)
    gu = cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gv = cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    vv, uu = np.mgrid[r0:r1, c0:c1].astype(np.float32)
    qu, qv = (uu + 0.5) / s - 0.5, (vv + 0.5) / s - 0.5
    maps = comp.maps_h(H1, s, True)
    road = _warp_window(middle.astype(np.float32), maps, qu, qv, s)
    explained = det._road_explained(a, gu, gv, road)
    p = patch[r0:r1, c0:c1]
    inner = cv2.erode(p.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    road = ~(cv2.dilate(p.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0)
    edge = (gu * gu + gv * gv) >= cfg.refine_min_gradient**2
    assert (inner & edge).sum() > 50 and (road & edge).sum() > 500
    assert explained[road & edge].mean() > 0.95
    # unrelated texture agrees within the floor (~15 grey levels on these edges) by chance
    # at ~2 * 15 / 255 of the pixels
    assert explained[inner & edge].mean() < 0.25
