"""The per-eye bias a session's own lines show (``estimator.slippage.seen_bias``): fixations whose
eyes' lines sit off their point beyond the noise (a bias the calibration did not see) give their
bias; consistent fixations give none."""

import numpy as np
import pytest

from estimator import BinocularSamples, perturb_directions
from estimator.frames import rotation_about_axis
from estimator.slippage import seen_bias


def _turn(d, h_deg, v_deg):
    """Directions (n, 3) turned as the simulator turns an eye's: about y by h, about x by -v."""
    R = rotation_about_axis([0, 1, 0], np.deg2rad(h_deg)) @ rotation_about_axis([1, 0, 0], -np.deg2rad(v_deg))
    return d @ R.T


def _session(rng, bias_deg, n_fix=10, n=90, travel_mm=300.0):
    """Fixations of points at 0.5-5 m from a head walking ``travel_mm`` over each, each eye's
    lines turned by its (h, v) ``bias_deg``, 1 deg noise; (samples, fixation labels)."""
    parts, labels, t0 = [], [], 0.0
    for k in range(n_fix):
        X = np.array([rng.uniform(-800, 800), rng.uniform(-400, 400), rng.uniform(500, 5000)])
        heads = np.column_stack([np.linspace(0, travel_mm, n) + rng.uniform(-200, 200), np.zeros(n),
                                 np.linspace(0, travel_mm / 2, n)])
        lo, ro = heads - [32.5, 0, 0], heads + [32.5, 0, 0]
        dirs = [_turn((X - o) / np.linalg.norm(X - o, axis=1, keepdims=True), *b)
                for o, b in zip((lo, ro), bias_deg, strict=True)]
        s = np.deg2rad(1.0)
        parts.append(BinocularSamples.from_arrays(t0 + np.arange(n) / 60, lo, perturb_directions(dirs[0], s, rng), ro,
                                                  perturb_directions(dirs[1], s, rng)))
        labels += [k] * n
        t0 += n / 60 + 0.3
    return BinocularSamples.concatenate(parts), np.array(labels)


@pytest.mark.parametrize("bias", [[[0.4, 0.3], [-0.4, -0.3]], [[0.15, -0.1], [-0.1, 0.15]]])
def test_an_over_dispersed_session_shows_its_bias(bias):
    rng = np.random.default_rng(11)
    b = np.asarray(bias)
    seen = [seen_bias(*_session(rng, b)) for _ in range(3)]
    true = float(np.sqrt(np.mean(((b[0] - b[1]) / np.sqrt(2)) ** 2)))     # what lines show: the eyes' differences
    for s in seen:
        assert s.groups == 10 and s.left_out == 0 and s.seen >= 2
        assert s.deg == pytest.approx(true, rel=0.35), (s, true)
        assert s.se_deg < true


def test_consistent_fixations_show_no_bias():
    rng = np.random.default_rng(12)
    seen = [seen_bias(*_session(rng, np.zeros((2, 2)))) for _ in range(4)]
    assert all(s.groups == 10 and s.seen >= 2 for s in seen)
    assert max(s.deg for s in seen) < 3 * max(s.se_deg for s in seen) < 0.15     # noise alone: within its error


def test_a_group_far_noisier_than_the_others_is_left_out_and_labels_are_checked():
    rng = np.random.default_rng(13)
    samples, labels = _session(rng, np.zeros((2, 2)), n_fix=6)
    noisy = labels == 5                                     # a missed saccade: 5 deg of scatter
    ld, rd = samples.left_direction.copy(), samples.right_direction.copy()
    ld[noisy] = perturb_directions(ld[noisy], np.deg2rad(5.0), rng)
    rd[noisy] = perturb_directions(rd[noisy], np.deg2rad(5.0), rng)
    bad = BinocularSamples.from_arrays(samples.t_s, samples.left_origin_mm, ld, samples.right_origin_mm, rd)
    s = seen_bias(bad, labels)
    assert s.groups == 5 and s.left_out == 1 and s.deg < 0.1
    none = seen_bias(samples, np.full(len(samples), -1))
    assert none.groups == 0 and none.deg == 0.0
    with pytest.raises(ValueError, match="labels"):
        seen_bias(samples, labels[:-1])
