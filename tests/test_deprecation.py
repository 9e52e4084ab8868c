"""Renamed names (issue 30: identifiers spelled the American way) still work for one release and
warn: the helper of ``estimator.deprecation`` and every old name the project keeps.

Old names are written as strings here (``**{"centre_mm": ...}``, ``getattr(m, "to_grey")``): the
renaming script rewrites identifiers, so old names written as identifiers would be renamed too."""

import dataclasses
import importlib
import inspect
import types
import warnings

import numpy as np
import pytest

from estimator.deprecation import module_getattr, renamed_kwargs

OLD_NAME = "'old' is deprecated, use 'new'"


@renamed_kwargs({"old": "new"})
def _scaled(x, new=1.0):
    return x * new


def test_an_old_keyword_is_passed_as_the_new_one_with_a_warning_at_the_caller():
    with pytest.warns(DeprecationWarning, match=OLD_NAME) as rec:
        assert _scaled(2.0, **{"old": 3.0}) == 6.0
    assert rec[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")                    # the new name: no warning
        assert _scaled(2.0, new=3.0) == 6.0 and _scaled(2.0) == 2.0


def test_an_old_and_a_new_keyword_together_are_a_type_error():
    with pytest.raises(TypeError, match="both 'old' and its new name 'new'"):
        _scaled(2.0, **{"old": 3.0, "new": 4.0})


@renamed_kwargs({"old": "new", "old_method": "new_method"})
@dataclasses.dataclass(frozen=True)
class _Record:
    new: float
    other: int = 0

    def new_method(self) -> float:
        return 2 * self.new


def test_a_class_takes_an_old_field_name_and_reads_old_attributes_with_a_warning():
    with pytest.warns(DeprecationWarning, match=OLD_NAME):
        r = _Record(**{"old": 1.5})
    assert r == _Record(1.5) and dataclasses.asdict(r) == {"new": 1.5, "other": 0}
    with pytest.warns(DeprecationWarning, match="'old_method' is deprecated, use 'new_method'"):
        assert r.old_method() == 3.0
    with pytest.warns(DeprecationWarning, match=OLD_NAME):
        assert r.old == 1.5


@renamed_kwargs({"old_method": "new_method"})
@dataclasses.dataclass(frozen=True)
class _OnlyAMethod:
    value: float


def test_a_class_whose_constructor_lost_no_name_keeps_its_own_constructor():
    assert not hasattr(_OnlyAMethod.__init__, "__wrapped__")
    assert hasattr(_Record.__init__, "__wrapped__")


def test_a_module_serves_an_old_name_with_a_warning_and_nothing_else():
    namespace = {"__name__": "somewhere", "new": object()}
    getter = module_getattr(namespace, {"old": "new"})
    with pytest.warns(DeprecationWarning, match="somewhere: " + OLD_NAME):
        assert getter("old") is namespace["new"]
    with pytest.raises(AttributeError, match="'somewhere' has no attribute 'other'"):
        getter("other")


MODULE_NAMES = [
    ("calibration.eyes", "estimate_centre", "estimate_center"),
    ("calibration.images", "to_grey", "to_gray"),
    ("estimator.merge", "RELINEARISE_GROWTH", "RELINEARIZE_GROWTH"),
    ("tracking.localise", "FeatureLocaliser", "FeatureLocalizer"),
    ("wearable_gaze.formats.images", "read_grey_image", "read_gray_image"),
    ("wearable_gaze.formats.video", "grey_frames", "gray_frames"),
    ("wearable_gaze.formats.video", "grey_frames_at", "gray_frames_at"),
    ("wearable_gaze.formats.video", "sampled_grey_frames", "sampled_gray_frames"),
    ("wearable_gaze.formats.devices.pupil_cloud_eyes", "CENTRE_COLS", "CENTER_COLS"),
    ("wearable_gaze.pipeline.steps.calibrate", "NOMINAL_CENTRES_MM", "NOMINAL_CENTERS_MM"),
    ("wearable_gaze.pipeline.report.plots", "COLOURS", "COLORS"),
    ("wearable_gaze.pipeline.report.page", "colour", "color"),
    ("wearable_gaze.pipeline.report.page", "COLOURS", "COLORS"),
    ("wearable_gaze.pipeline.steps.aoi", "AOI_COLOUR", "AOI_COLOR"),
    ("wearable_gaze.pipeline.steps.export", "COLOURS", "COLORS"),
    ("wearable_gaze.pipeline.steps.export", "HEAD_COLOUR", "HEAD_COLOR"),
    ("wearable_gaze.pipeline.report.overlay", "EYE_COLOURS", "EYE_COLORS"),
]


@pytest.mark.parametrize(("module", "old", "new"), MODULE_NAMES)
def test_each_renamed_module_name_is_still_importable_and_warns(module, old, new):
    m = importlib.import_module(module)
    with pytest.warns(DeprecationWarning, match=f"{module}: '{old}' is deprecated, use '{new}'"):
        assert getattr(m, old) is getattr(m, new)
    with pytest.warns(DeprecationWarning):
        exec(f"from {module} import {old} as got", scope := {})
    assert scope["got"] is getattr(m, new)


KEYWORDS = [          # (module, callable, {old: new}): functions, and classes' constructors
    ("calibration.eyes", "plane_points", {"centre_mm": "center_mm"}),
    ("calibration.eyes", "calibrate_eye", {"centre_mm": "center_mm"}),
    ("calibration.eyes", "compare_models", {"centre_mm": "center_mm"}),
    ("calibration.eyes", "EyeCalibration", {"centre_mm": "center_mm"}),
    ("calibration.eyes", "RawMap", {"centre": "center"}),
    ("tracking.localise", "image_features", {"grey": "gray"}),
    ("tracking.localise", "FeatureLocalizer.estimate", {"grey": "gray"}),
    ("wearable_gaze.formats.ply", "PlyMesh", {"colours": "colors"}),
    ("wearable_gaze.formats.devices.pupil_cloud_eyes", "eye_validity", {"centres": "centers"}),
    ("wearable_gaze.formats.devices.pupil_cloud_eyes", "visual_axes", {"centres": "centers"}),
    ("wearable_gaze.formats.devices.pupil_cloud_eyes", "write_eye_states", {"centres": "centers"}),
    ("wearable_gaze.paper.calstudy", "StudyResult", {"centre_errors_mm": "center_errors_mm"}),
    ("wearable_gaze.paper.calstudy", "StudyResult", {"centre_sigma_mm": "center_sigma_mm"}),
    ("wearable_gaze.paper.calstudy", "run_calibration_study",
     {"centre_samples_per_target": "center_samples_per_target"}),
    ("wearable_gaze.pipeline.steps.calibrate", "check_frame_size", {"grey": "gray"}),
    ("wearable_gaze.pipeline.steps.calibrate", "calibrate_eyes_files", {"centres": "centers"}),
    ("wearable_gaze.pipeline.steps.calibrate", "calibrate_eyes", {"centres": "centers"}),
    ("wearable_gaze.pipeline.report.plots", "write_plots", {"colour": "color"}),
    ("wearable_gaze.pipeline.report.plots", "figure_3d", {"colour": "color"}),
    ("wearable_gaze.pipeline.report.plots", "figure_top", {"colour": "color"}),
    ("wearable_gaze.pipeline.report.timeline", "plot_depth_over_time", {"colour": "color"}),
    ("wearable_gaze.pipeline.report.page", "ReportData", {"centre": "center"}),
    ("wearable_gaze.pipeline.process.stepconf", "EyesConfig", {"centres": "centers"}),
    ("wearable_gaze.pipeline.report.view3d", "SceneTarget", {"colour": "color"}),
    ("wearable_gaze.sim.eyes", "EyeModel", {"centres": "centers"}),
    ("wearable_gaze.sim.eyes", "EyeModel.make", {"centre_offset_mm": "center_offset_mm"}),
]


def _resolve(module: str, dotted: str):
    obj = importlib.import_module(module)
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


@pytest.mark.parametrize(("module", "name", "renames"), KEYWORDS,
                         ids=[f"{k[1]}-{next(iter(k[2]))}" for k in KEYWORDS])
def test_each_renamed_keyword_is_mapped_to_its_new_name(module, name, renames):
    """The callable takes the new name, and the old one is mapped onto it (both at once: the
    wrapper's TypeError, before the body runs)."""
    f = _resolve(module, name)
    (old, new), = renames.items()
    assert new in inspect.signature(f).parameters and old not in inspect.signature(f).parameters
    with pytest.raises(TypeError, match=f"both '{old}' and its new name '{new}'"):
        f(**{old: None, new: None})


@pytest.mark.parametrize(("module", "name", "renames"),
                         [k for k in KEYWORDS if isinstance(_resolve(k[0], k[1]), type)]
                         + [("estimator.mergeform", "MergeForm", {"centred": "centered"})])
def test_each_renamed_attribute_reads_the_new_one_with_a_warning(module, name, renames):
    cls = _resolve(module, name)
    (old, new), = renames.items()
    value = object()
    with pytest.warns(DeprecationWarning, match=f"'{old}' is deprecated, use '{new}'"):
        assert getattr(cls, old).fget(types.SimpleNamespace(**{new: value})) is value


def test_the_old_british_keywords_give_the_same_results():
    """End to end on two of them: the calibration plane's points and the simulated eyes."""
    from calibration.eyes import EyeCalibration, plane_points
    from wearable_gaze.sim.eyes import EyeModel
    targets = np.array([[100.0, -50.0, 1000.0], [-200.0, 80.0, 1500.0]])
    eye = np.array([30.0, 20.0, -15.0])
    with pytest.warns(DeprecationWarning, match="'centre_mm' is deprecated, use 'center_mm'"):
        old = plane_points(targets, **{"centre_mm": eye, "plane_mm": 800.0})
    np.testing.assert_array_equal(old, plane_points(targets, center_mm=eye, plane_mm=800.0))
    with pytest.warns(DeprecationWarning):
        cal = EyeCalibration("left", **{"centre_mm": eye}, plane_mm=800.0, raw_map=None)
    assert cal.center_mm is eye
    with pytest.warns(DeprecationWarning):
        a = EyeModel.make(np.random.default_rng(0), 60.0, **{"centre_offset_mm": (1.0, 2.0, 3.0)})
    b = EyeModel.make(np.random.default_rng(0), 60.0, center_offset_mm=(1.0, 2.0, 3.0))
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.centers, [[-29.0, 2.0, 3.0], [31.0, 2.0, 3.0]])
