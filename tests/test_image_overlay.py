"""The camera view's overlay geometry (testbed.viz.image_overlay) against brute force: dense samples
of each segment, kept where they are in front of the camera and inside the image."""

import numpy as np

from testbed.viz.image_overlay import NEAR_M, clip_to_rect, declutter, horizon, image_segments

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
W, H = 640.0, 480.0


def _visible_span(A, B, n=20001):
    """The first and last dense sample of camera-frame segment A B in front and inside the image, px."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    X = A + s * (B - A)
    front = X[:, 2] >= NEAR_M
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (X @ K.T)[:, :2] / X[:, 2:3]
    ok = front & (uv[:, 0] >= 0) & (uv[:, 0] <= W) & (uv[:, 1] >= 0) & (uv[:, 1] <= H)
    return (uv[ok][[0, -1]] if ok.any() else None), ok.mean()


def test_segments_are_cut_to_the_part_in_front_of_the_camera_and_inside_the_image():
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(300):
        A, B = rng.uniform([-300, -300, -200], [300, 300, 800], (2, 3))
        got = image_segments(K, W, H, np.array([[A, B]]))
        want, share = _visible_span(A, B)
        if want is None or share < 1e-3:  # nothing (or a sliver) visible
            assert len(got) == 0 or np.linalg.norm(got[0][1] - got[0][0]) < 5.0
            continue
        assert len(got) == 1
        ends = got[0]
        # the same end points, in either order, to the sampling's resolution
        err = min(np.abs(ends - want).max(), np.abs(ends[::-1] - want).max())
        assert err < 2.0, (A, B, ends, want)
        checked += 1
    assert checked > 50


def test_clip_to_rect_keeps_a_segment_inside_and_drops_one_outside():
    p, q = np.array([10.0, 10.0]), np.array([20.0, 30.0])
    np.testing.assert_allclose(clip_to_rect(p, q, W, H), (p, q))
    assert clip_to_rect(np.array([-10.0, -5.0]), np.array([-1.0, 500.0]), W, H) is None


def test_no_horizon_when_looking_straight_down():
    down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # camera z = world -z
    assert horizon(K, W, H, down).shape == (0, 2, 2)


def test_declutter_keeps_the_first_of_overlapping_labels():
    uv = np.array([[100.0, 100.0], [110.0, 104.0], [300.0, 100.0], [305.0, 130.0]])
    np.testing.assert_array_equal(declutter(uv, (50.0, 20.0)), [True, False, True, True])
    np.testing.assert_array_equal(declutter(uv, (50.0, 20.0), order=[1, 0, 2, 3]), [False, True, True, True])
