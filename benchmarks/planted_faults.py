"""Twelve planted faults (issue 30): one per pipeline step and one per library's maths, each a
plausible one-line bug a careful reader of the code might make (a sign, a transposed transform,
an off-by-one at a boundary, a wrong chi-square's degrees of freedom, degrees for radians), each
expected to be caught by at least two tests.

    python benchmarks/planted_faults.py [--only NAME ...] [--jobs N] [--work DIR] [--keep]
    python benchmarks/planted_faults.py --discover tests/test_x.py [...] [--only NAME ...]

For each fault the tracked files of the repository (as they are in the working tree) are copied
to a folder of their own, the fault's ``anchor`` (one line of ``file``, which must occur in it
exactly once, so that the list stays honest when the code moves: the script stops with the
fault's name otherwise) is replaced by its ``replacement``, and each of the fault's ``tests`` is
run on the copy in a pytest of its own (``-x -q -p no:cacheprovider``; one node per process, so
that ``-x`` cannot hide the second catch), ``--jobs`` at a time. First the same tests run on an
unchanged copy: all must pass. It prints a table (fault, the tests that failed, how many) and
exits 1 when the clean run fails or a fault is caught by fewer than two tests, 2 when an anchor
or a test id is stale.

``--discover FILE...`` runs whole test files (no ``-x``) on each fault's copy and prints the
ids of the tests that fail: how the lists below were found, and how to re-find them after the
code moved.

Measured on 2026-12-03 (branch faults30, from main 602ed13; 2 jobs, load average 11-13 on 2
cores shared with other work: 448 s wall, 440 s in a second run with the same table, for the clean
run and the 29 fault runs; the seconds are the sum of each fault's pytest processes under that
load, mostly start-up and fixtures). Before
this branch, 6 of the 12 were caught by fewer than two tests of the files searched (``--discover``
over test_roundtrips, test_lines, test_calibration, test_tracking, test_errormodel, test_segments,
test_merge, test_aoi, test_regions, test_direction_only, test_triangulation; test_import and
test_exports read for the clock): ``eye-plane-centre-depth`` and ``segment-gap-off-by-one`` by
none, ``camera-reject-best``, ``pnp-ambiguity-farther``, ``export-clock-offset-sign`` and
``aoi-cone-degrees`` by one. The tests that catch them now were written for them (each names its
fault)::

    fault                          caught     s  tests that failed
    camera-reject-best                2/2    57  test_calibration::test_a_bad_view_is_rejected_with_its_reason,
                                                 test_calibration::test_the_worst_of_projected_views_is_the_one_...
    eye-plane-centre-depth            2/2    27  test_calibration::test_plane_points_put_each_target_on_its_line_...,
                                                 test_calibration::test_an_eye_calibrated_at_two_wall_distances_...
    pnp-ambiguity-farther             2/2    35  test_tracking::test_single_marker_sequence_has_no_flips,
                                                 test_tracking::test_one_markers_ambiguity_is_resolved_toward_the_...
    pose-slerp-transposed             3/3    52  test_calibration::test_interpolate_poses_slerps_and_refuses_gaps,
                                                 test_calibration::test_pose_spikes_are_the_poses_that_jump_off_...,
                                                 test_exports::test_gaze_columns_of_hand_made_samples_carry_the_...
    segment-gap-off-by-one            2/2    26  test_segments::test_a_time_gap_ends_a_fixation_at_its_last_sample_...,
                                                 test_segmentation_cmd::test_fixations_file_ends_a_fixation_at_a_...
    merge-test-inverted               2/2    58  test_merge::test_a_revisit_joins_its_target_which_is_estimated_...,
                                                 test_merge::test_live_ids_partition_the_fixations_as_process_...
    export-clock-offset-sign          2/2   176  test_exports::test_gaze_columns_of_hand_made_samples_carry_the_...,
                                                 test_import::test_device_rays_and_poses_find_the_targets_as_well_...
    aoi-cone-degrees                  2/2    27  test_aoi::test_a_direction_only_fixation_lands_on_what_its_ray_meets,
                                                 test_aoi::test_a_direction_only_spread_holds_95_percent_of_its_...
    viewline-direction-transposed     3/3    39  test_lines::test_world_camera_round_trip_matches_paper_eq_5_to_8,
                                                 test_lines::test_view_lines_to_world_takes_the_pose_either_way_round,
                                                 test_roundtrips::test_view_lines_to_the_world_and_back_keep_every_...
    k95-two-dof                       2/2    28  test_roundtrips::test_k95_is_the_square_root_of_chi_square_3_at_95_...,
                                                 test_errormodel::test_each_level_has_its_own_far_side_and_the_95_...
    undistort-one-iteration           3/3   101  test_roundtrips::test_undistortion_inverts_opencvs_projection[pinhole],
                                                 test_tracking::test_ransac_drops_a_marker_with_wrong_corners,
                                                 test_calibration::test_calibrate_eyes_and_viewlines_on_a_rendered_...
    pose-covariance-transposed        3/3    38  test_roundtrips::test_the_world_pose_covariance_is_the_monte_carlo_one,
                                                 test_tracking::test_pose_covariance_describes_the_world_from_cam_...,
                                                 test_tracking::test_world_pose_jacobian_matches_finite_differences
    12 of 12 faults caught by at least two tests

Other tests catch some of them too (``--discover``): ``merge-test-inverted`` also
test_aoi::test_a_targets_dwell_is_the_sum_of_its_fixations_not_its_span (the ``processed``
session, a minute), ``undistort-one-iteration`` five more of test_calibration and test_tracking,
``pose-slerp-transposed`` test_tracking::test_track_cli_writes_poses_and_an_overlay,
``viewline-direction-transposed`` test_lines::test_per_line_poses; the list keeps the cheaper ones.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYTEST = ("-x", "-q", "-p", "no:cacheprovider")
CAL = "tests/test_calibration.py::"
TRACK = "tests/test_tracking.py::"
ROUND = "tests/test_roundtrips.py::"
EXPORTS = "tests/test_exports.py::"
SEG = "tests/test_segments.py::"
SEGCMD = "tests/test_segmentation_cmd.py::"
MERGE = "tests/test_merge.py::"
IMPORT = "tests/test_import.py::"
AOI = "tests/test_aoi.py::"
LINES = "tests/test_lines.py::"
ERRM = "tests/test_errormodel.py::"


@dataclass(frozen=True)
class Fault:
    """One planted fault.

    Attributes:
        name: short name (``--only``).
        concept: the step or the library maths it breaks.
        file: the file it is planted in, relative to the repository.
        anchor: one line's text (stripped of its indentation) found exactly once in ``file``.
        replacement: what the anchor becomes.
        tests: pytest node ids expected to fail with the fault in place (at least two).
    """

    name: str
    concept: str
    file: str
    anchor: str
    replacement: str
    tests: tuple[str, ...]


FAULTS = (
    # --- one per step ---------------------------------------------------------------------------
    Fault("camera-reject-best", "step: camera calibration (a bad view rejected)",
          "calibration/camera.py",
          "worst = int(np.argmax(per))",
          "worst = int(np.argmin(per))",
          (CAL + "test_a_bad_view_is_rejected_with_its_reason",
           CAL + "test_the_worst_of_projected_views_is_the_one_rejected_and_the_rest_give_the_intrinsics")),
    Fault("eye-plane-centre-depth", "step: eye calibration (eq. 3-4's plane points)",
          "calibration/eyes.py",
          "s = (plane_mm - e[2]) / (P[:, 2] - e[2])",
          "s = plane_mm / P[:, 2]",
          (CAL + "test_plane_points_put_each_target_on_its_line_from_the_eye_centre",
           CAL + "test_an_eye_calibrated_at_two_wall_distances_reproduces_every_target")),
    Fault("pnp-ambiguity-farther", "step: tracking (a single marker's IPPE ambiguity by continuity)",
          "tracking/pose.py",
          "choice = min(cands, key=lambda c: np.linalg.norm(c[1][:3, 3] - prev[:3, 3]))",
          "choice = max(cands, key=lambda c: np.linalg.norm(c[1][:3, 3] - prev[:3, 3]))",
          (TRACK + "test_single_marker_sequence_has_no_flips",
           TRACK + "test_one_markers_ambiguity_is_resolved_toward_the_previous_pose")),
    Fault("pose-slerp-transposed", "step: view lines (head poses interpolated to the eye samples)",
          "tracking/timeline.py",
          "out[sel, :3, :3] = slerp(tt).as_matrix()",
          "out[sel, :3, :3] = slerp(tt).inv().as_matrix()",
          (CAL + "test_interpolate_poses_slerps_and_refuses_gaps",
           CAL + "test_pose_spikes_are_the_poses_that_jump_off_a_smooth_head_and_back",
           EXPORTS + "test_gaze_columns_of_hand_made_samples_carry_the_device_clock_and_the_world_lines")),
    Fault("segment-gap-off-by-one", "step: segmentation (a time gap's boundary)",
          "estimator/segments.py",
          "gaps = np.flatnonzero(np.diff(tv) > config.max_gap_s) + 1",
          "gaps = np.flatnonzero(np.diff(tv) > config.max_gap_s)",
          (SEG + "test_a_time_gap_ends_a_fixation_at_its_last_sample_exactly",
           SEGCMD + "test_fixations_file_ends_a_fixation_at_a_time_gap_to_the_sample")),
    Fault("merge-test-inverted", "step: targets (a revisit merged by the likelihood-ratio test)",
          "estimator/merge.py",
          "if lr < MERGE_LR_THRESHOLD:",
          "if lr > MERGE_LR_THRESHOLD:",
          (MERGE + "test_a_revisit_joins_its_target_which_is_estimated_again_and_a_poorly_fixed_fixation_does_not",
           MERGE + "test_live_ids_partition_the_fixations_as_process_merges_the_same_lines")),
    Fault("export-clock-offset-sign", "step: export (gaze.csv's device clock)",
          "wearable_gaze/pipeline/export.py",
          'cols = {"sample": np.arange(n), "t_s": head.t_s, "device_t_s": head.t_s + clock_offset_s,',
          'cols = {"sample": np.arange(n), "t_s": head.t_s, "device_t_s": head.t_s - clock_offset_s,',
          (EXPORTS + "test_gaze_columns_of_hand_made_samples_carry_the_device_clock_and_the_world_lines",
           IMPORT + "test_device_rays_and_poses_find_the_targets_as_well_as_the_native_session")),
    Fault("aoi-cone-degrees", "step: AOI (a direction-only fixation's cone in degrees as radians)",
          "estimator/aoi.py",
          "sd = math.radians(cone95_deg) / math.sqrt(chi2.ppf(0.95, 2))",
          "sd = cone95_deg / math.sqrt(chi2.ppf(0.95, 2))",
          (AOI + "test_a_direction_only_fixation_lands_on_what_its_ray_meets",
           AOI + "test_a_direction_only_spread_holds_95_percent_of_its_draws_in_its_cone")),
    # --- one per library's maths ----------------------------------------------------------------
    Fault("viewline-direction-transposed", "estimator maths: the view-line transform (eq. 7-8)",
          "estimator/lines.py",
          'rotate_directions(T_wc, lines_cam.directions), "world", lines_cam.sample_index)',
          'rotate_directions(invert(T_wc), lines_cam.directions), "world", lines_cam.sample_index)',
          (LINES + "test_world_camera_round_trip_matches_paper_eq_5_to_8",
           LINES + "test_view_lines_to_world_takes_the_pose_either_way_round",
           ROUND + "test_view_lines_to_the_world_and_back_keep_every_gazed_point")),
    Fault("k95-two-dof", "estimator maths: the 95 % ellipsoid's scale (chi-square's dof)",
          "estimator/errormodel.py",
          "K95 = math.sqrt(chi2.ppf(0.95, 3))",
          "K95 = math.sqrt(chi2.ppf(0.95, 2))",
          (ROUND + "test_k95_is_the_square_root_of_chi_square_3_at_95_percent",
           ERRM + "test_each_level_has_its_own_far_side_and_the_95_percent_one_is_the_covariance")),
    Fault("undistort-one-iteration", "calibration maths: undistortion (iterated to convergence)",
          "calibration/camera.py",
          "return cvcompat.undistort_points(p, camera_matrix, dist_coeffs, 50, 1e-10)",
          "return cvcompat.undistort_points(p, camera_matrix, dist_coeffs, 1, 1e-10)",
          (ROUND + "test_undistortion_inverts_opencvs_projection[pinhole]",
           TRACK + "test_ransac_drops_a_marker_with_wrong_corners",
           CAL + "test_calibrate_eyes_and_viewlines_on_a_rendered_session")),
    Fault("pose-covariance-transposed", "tracking maths: the pose covariance propagated to the world",
          "tracking/pnp.py",
          "A[3:, 3:] = -R_wc",
          "A[3:, 3:] = -R_wc.T",
          (ROUND + "test_the_world_pose_covariance_is_the_monte_carlo_one",
           TRACK + "test_pose_covariance_describes_the_world_from_cam_pose_it_sits_beside",
           TRACK + "test_world_pose_jacobian_matches_finite_differences")),
)


# --- the copies -------------------------------------------------------------------------------------

def tracked_files(root: Path) -> list[str]:
    """The repository's tracked files that exist in the working tree (paths relative to it)."""
    out = subprocess.run(["git", "ls-files", "-z"], cwd=root, check=True, capture_output=True).stdout
    return [p for p in out.decode().split("\0") if p and (root / p).is_file()]


def copy_tree(root: Path, files: list[str], dst: Path) -> None:
    """The ``files`` of ``root`` copied into ``dst``."""
    for rel in files:
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / rel, dst / rel)


def planted(text: str, fault: Fault) -> str:
    """``text`` with the fault's anchor replaced; ValueError unless the anchor is on exactly one
    line (compared without indentation) and nowhere else."""
    if text.count(fault.anchor) != 1:
        raise ValueError(f"{fault.name}: the anchor occurs {text.count(fault.anchor)} times in {fault.file}, "
                         f"not once: {fault.anchor!r}")
    return text.replace(fault.anchor, fault.replacement)


def plant(clean: Path, fault: Fault, dst: Path) -> None:
    """A copy of ``clean`` in ``dst`` (hard links) with the fault planted (a file of its own)."""
    shutil.copytree(clean, dst, copy_function=os.link)
    target = dst / fault.file
    text = planted(target.read_text(), fault)
    target.unlink()
    target.write_text(text)


# --- running tests ----------------------------------------------------------------------------------

def _env(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
    real = ROOT.parent / "shared" / "data" / "real"
    if "WEARABLE_GAZE_REAL_DATA" not in env and real.is_dir():
        env["WEARABLE_GAZE_REAL_DATA"] = str(real)        # the copy is not beside ../shared
    return env


def run_pytest(tree: Path, args: list[str]) -> tuple[int, str, float]:
    """(exit status, output, seconds) of pytest with ``args`` in ``tree``."""
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "pytest", *args], cwd=tree, env=_env(tree), capture_output=True,
                       text=True)
    return p.returncode, p.stdout + p.stderr, time.perf_counter() - t0


def run_node(tree: Path, node: str) -> tuple[str, int, str, float]:
    """(node, exit status, last output lines, seconds) of one test node, ``-x``."""
    rc, out, s = run_pytest(tree, [*PYTEST, node])
    return node, rc, "\n".join(out.strip().splitlines()[-3:]), s


FAILED = re.compile(r"^(?:FAILED|ERROR) (\S+)", re.M)


def discover(tree: Path, files: list[str]) -> list[str]:
    """The ids of the tests of ``files`` that fail in ``tree`` (whole files, no ``-x``)."""
    _, out, _ = run_pytest(tree, ["-q", "-p", "no:cacheprovider", "-rfE", *files])
    return sorted(set(FAILED.findall(out)))


# --- main -------------------------------------------------------------------------------------------

def check_anchors(faults) -> None:
    """Each fault's anchor found exactly once in its file, or exit 2 naming the stale ones."""
    bad = []
    for f in faults:
        try:
            planted((ROOT / f.file).read_text(), f)
        except (ValueError, OSError) as exc:
            bad.append(str(exc))
    if bad:
        print("stale planted faults (re-anchor them):\n  " + "\n  ".join(bad), file=sys.stderr)
        sys.exit(2)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", help="the faults to plant (names)")
    ap.add_argument("--jobs", type=int, default=2, help="pytest processes at a time")
    ap.add_argument("--work", type=Path, help="where the copies go (default: a temporary folder)")
    ap.add_argument("--keep", action="store_true", help="keep the copies")
    ap.add_argument("--discover", nargs="+", metavar="TEST_FILE",
                    help="print each fault's failing tests of these files")
    return ap.parse_args(argv)


def _table(rows) -> str:
    """The table: each fault, how many of its tests failed (of how many run), the seconds its
    tests took, and the failed tests' names (without ``tests/`` and ``.py``)."""
    lines = [f"{'fault':<30} {'caught':>6} {'s':>5}  tests that failed"]
    for name, failed, n, seconds, errors in rows:
        short = [t.replace("tests/", "").replace(".py::", "::") for t in failed]
        lines.append(f"{name:<30} {f'{len(failed)}/{n}':>6} {seconds:>5.0f}  {', '.join(short) or '-'}"
                     + (f"  ERRORS: {', '.join(errors)}" if errors else ""))
    return "\n".join(lines)


def main(argv=None) -> int:
    args = parse_args(argv)
    faults = [f for f in FAULTS if not args.only or f.name in args.only]
    if args.only and len(faults) != len(set(args.only)):
        print(f"unknown fault names; known: {', '.join(f.name for f in FAULTS)}", file=sys.stderr)
        return 2
    check_anchors(faults)
    work = Path(tempfile.mkdtemp(prefix="planted_faults_", dir=args.work))
    try:
        clean = work / "clean"
        copy_tree(ROOT, tracked_files(ROOT), clean)
        for f in faults:
            plant(clean, f, work / f.name)
        if args.discover:
            for f in faults:
                print(f"{f.name}: {discover(work / f.name, args.discover)}", flush=True)
            return 0
        return _measure(faults, clean, work, args.jobs)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
        else:
            print(f"copies kept in {work}")


def _measure(faults, clean: Path, work: Path, jobs: int) -> int:
    nodes = sorted({n for f in faults for n in f.tests})
    t0 = time.perf_counter()
    rc, out, _ = run_pytest(clean, [*PYTEST, *nodes])
    if rc in (4, 5):                                      # usage error: a test id not found
        print(f"a test id is stale (pytest exit {rc}):\n{out[-3000:]}")
        return 2
    if rc != 0:
        print(f"the clean run fails (exit {rc}):\n{out[-3000:]}")
        return 1
    print(f"clean run: {len(nodes)} tests pass ({time.perf_counter() - t0:.0f} s)", flush=True)
    jobs_list = [(f, n) for f in faults for n in f.tests]
    with ThreadPoolExecutor(max(1, jobs)) as pool:
        results = list(pool.map(lambda fn: (fn[0].name, run_node(work / fn[0].name, fn[1])), jobs_list))
    rows, short, stale = [], [], False
    for f in faults:
        mine = [r for name, r in results if name == f.name]
        failed = [n for n, rc, _, _ in mine if rc == 1]
        errors = [f"{n} (exit {rc}: {tail.splitlines()[-1] if tail else ''})" for n, rc, tail, _ in mine
                  if rc not in (0, 1)]
        stale |= bool(errors)
        rows.append((f.name, failed, len(mine), sum(r[3] for r in mine), errors))
        if len(failed) < 2:
            short.append(f.name)
    print(_table(rows))
    print(f"{len(faults) - len(short)} of {len(faults)} faults caught by at least two tests "
          f"({sum(s for *_, s in (r for _, r in results)):.0f} s of test runs, {jobs} at a time)")
    if stale:
        return 2
    return 1 if short else 0


if __name__ == "__main__":
    sys.exit(main())
