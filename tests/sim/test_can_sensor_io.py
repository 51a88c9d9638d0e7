"""CAN model, sensor effects and atomic writes."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimator import fileio as io
from estimator.camera.models import vignetting_gain
from sim.can import can_at, can_messages
from sim.sensor import SensorModel, apply_sensor, exposure_times, motion_blur, moving_blocks


def test_can_bias_noise_quantisation_and_rate():
    t = np.linspace(0, 10, 151)
    v = 20 + 0.5 * t
    rng = np.random.default_rng(0)
    tm, vm = can_messages(t, v, 50.0, 0.08, 0.3, 0.05, rng)
    assert np.allclose(np.diff(tm), 0.02)
    truth = np.interp(tm, t, v)
    assert abs(np.mean(vm / truth) - 1.08) < 0.005
    assert 0.25 < np.std(vm - 1.08 * truth) < 0.35
    assert np.allclose(vm / 0.05, np.round(vm / 0.05))
    held = can_at(np.array([0.0, 0.031, 10.0]), tm, vm)
    assert held[1] == vm[1]  # latest message at or before 31 ms is the one at 20 ms


def test_can_exact_when_off():
    t = np.linspace(0, 1, 16)
    tm, vm = can_messages(t, np.full(16, 12.3), 10.0, 0.0, 0.0, 0.0, np.random.default_rng(1))
    assert np.allclose(vm, 12.3)


def test_sensor_exact_is_identity():
    img = np.random.default_rng(0).integers(0, 256, (32, 40, 3), dtype=np.uint8)
    out = apply_sensor(img, SensorModel(), np.random.default_rng(0))
    assert np.array_equal(out, img)


def test_sensor_noise_and_jpeg_change_image_by_expected_amount():
    img = np.full((64, 64, 3), 128, np.uint8)
    out = apply_sensor(img, SensorModel(noise_std=3.0), np.random.default_rng(0))
    assert 2.5 < np.std(out.astype(float)) < 3.5
    out = apply_sensor(img, SensorModel(jpeg_quality=50), np.random.default_rng(0))
    assert out.shape == img.shape


def test_vignetting_and_blur():
    g = vignetting_gain((11, 11), 0.3)
    assert g[5, 5] == pytest.approx(1.0) and g[0, 0] == pytest.approx(0.7)
    img = np.zeros((20, 20, 3), np.float32)
    img[:, 10] = 255
    flow = np.zeros((20, 20, 2), np.float32)
    flow[..., 0] = 4.0  # 4 px horizontal motion over the exposure spreads the vertical line
    out = motion_blur(img, [t * flow for t in exposure_times(1.0)])
    assert out[5, 10, 0] < 255 and out[5, 8, 0] > 0 and out[5, 5, 0] == 0
    np.testing.assert_array_equal(motion_blur(img, []), img)


def test_motion_blur_resamples_only_what_moves_inside_the_mask():
    """Pixels inside the mask are blurred exactly as without a mask; outside it a pixel
    is the sharp image or its blur, and most keep the sharp image."""
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 255, (96, 128, 3)).astype(np.float32)
    flow = np.zeros((96, 128, 2), np.float32)
    flow[:, :70] = rng.uniform(-3, 3, (96, 70, 2))  # columns 70.. stand still
    mask = np.zeros((96, 128), bool)
    mask[10:90, 5:120] = True
    samples = [t * flow for t in exposure_times(1.0)]
    whole = motion_blur(img, samples)
    masked = motion_blur(img, samples, mask)
    kept = motion_blur(img, [0 * d for d in samples])  # the sharp image, averaged
    np.testing.assert_array_equal(masked[mask], whole[mask])
    sharp = np.all(masked == kept, axis=2)
    assert np.all(sharp | np.all(masked == whole, axis=2))
    assert sharp[~mask].mean() > 0.5
    np.testing.assert_array_equal(masked[:, 72:], kept[:, 72:])
    np.testing.assert_allclose(kept, img, rtol=1e-6)
    assert not np.allclose(masked[20:80, 10:60], img[20:80, 10:60], atol=1.0)


@settings(max_examples=50, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 90), st.integers(1, 90))))
def test_moving_blocks_cover_every_moving_pixel_once(moving):
    cover = np.zeros(moving.shape, int)
    for rows, cols in moving_blocks(moving):
        assert moving[rows, cols].any()
        cover[rows, cols] += 1
    assert cover.max(initial=0) <= 1 and np.all(cover[moving] == 1)


@pytest.mark.parametrize("gain", [0.3, -0.3, 0.1])
def test_motion_blur_is_the_time_average_of_the_paths(gain):
    """A blob in a steady image motion that grows along it (a road point nearing the
    camera: v = 30 + gain (x - c) px per frame, exact paths exponential): the blurred
    blob's centroid is the exposure's time average of the sharp image, within 0.01 px
    (its shift 0.026 px at gain 0.3); a straight streak along each pixel's motion to the
    next frame (the blur before) was 0.043 px off at gain 0.3."""
    width, c, v0, frac = 240, 120.0, 30.0, 0.15  # frac: the exposure over the frame interval
    x = np.arange(width, dtype=np.float32)
    blob = np.exp(-0.5 * ((x - c) / 2.0) ** 2).astype(np.float32)
    img = np.repeat(np.repeat(blob[None, :, None], 5, 0), 3, 2)

    def path(z, t):  # where the point at z goes in t frame intervals
        return c + (z - c + v0 / gain) * np.exp(gain * t) - v0 / gain

    def moved(t):
        d = np.zeros((5, width, 2), np.float32)
        d[..., 0] = path(x, t) - x
        return d

    got = motion_blur(img, [moved(t) for t in exposure_times(frac)])[2, :, 0]
    ts = np.linspace(-0.5 * frac, 0.5 * frac, 2001)  # a pixel sees what was at path(x, -t)
    want = np.mean([np.interp(path(x, -t), x, blob) for t in ts], axis=0)
    ahead = moved(1.0)[2, :, 0]
    streak = np.mean(
        [np.interp(x + s * frac * ahead, x, blob) for s in np.linspace(-0.5, 0.5, 5)], 0
    )

    def centroid(a):
        return float((a * x).sum() / a.sum() - c)

    assert abs(centroid(got) - centroid(want)) < 0.01
    assert abs(centroid(streak) - centroid(want)) > 0.008  # what the straight streak gave
    assert got.max() < 0.9 * blob.max()  # and it is blurred


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "a.json"

    def broken(p):
        p.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        io.atomic_write(target, broken)
    assert list(tmp_path.iterdir()) == []
    io.write_json(target, {"x": np.float32(1.5)})
    assert target.read_text().strip().startswith("{")
