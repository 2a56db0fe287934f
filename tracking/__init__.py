"""Hand tracking: sources -> MediaPipe's HandLandmarker (the model shipped in `models/`) ->
palm pose + per-finger openness -> filters, and the mapping of the tracked hand into the
robot workspace.

Nothing here opens a camera or loads MediaPipe at import time. See docs/tracking.md.

Typical use::

    from dsteleop.tracking import HandTracker, TrackingStream, VideoFileSource, WorkspaceMapping

    stream = TrackingStream(VideoFileSource("hand.mp4", realtime=True)).start()
    mapping = WorkspaceMapping()
    sample = stream.latest()            # newest HandSample or None, never blocks
    if sample is not None and sample.detected:
        X_human = mapping.map(sample)   # HandState in the robot base frame, 4 fingers
    stream.stop()
"""

from dsteleop.tracking.detector import DetectorConfig, HandDetector, make_detector
from dsteleop.tracking.filters import (
    HandFilterConfig,
    OneEuroConfig,
    OneEuroFilter,
    SO3OneEuroFilter,
)
from dsteleop.tracking.landmarks import FINGER_NAMES
from dsteleop.tracking.mapping import (
    ROBOT_FINGERS,
    MappingConfig,
    WorkspaceMapping,
    robot_openness,
)
from dsteleop.tracking.pipeline import (
    HandTracker,
    TrackerConfig,
    TrackingStream,
    iter_frames,
    iter_samples,
)
from dsteleop.tracking.pose import (
    CameraIntrinsics,
    PalmPose,
    PoseConfig,
    estimate_palm_pose,
    finger_flexion,
    hand_scale_for_depth,
    palm_rotation,
)
from dsteleop.tracking.selection import HandSelector, SelectionConfig
from dsteleop.tracking.sources import (
    FrameSource,
    ImageFolderSource,
    VideoFileSource,
    WebcamSource,
    open_source,
)
from dsteleop.tracking.synthetic import (
    HandModel,
    LandmarkNoise,
    SyntheticSource,
    Trajectory,
    palm_facing_camera,
    scripted_trajectory,
    synthesize_detection,
)
from dsteleop.tracking.types import Detection, Frame, Handedness, HandSample

__all__ = [
    "FINGER_NAMES",
    "ROBOT_FINGERS",
    "CameraIntrinsics",
    "Detection",
    "DetectorConfig",
    "Frame",
    "FrameSource",
    "HandDetector",
    "HandFilterConfig",
    "HandModel",
    "HandSample",
    "HandSelector",
    "HandTracker",
    "Handedness",
    "ImageFolderSource",
    "LandmarkNoise",
    "MappingConfig",
    "OneEuroConfig",
    "OneEuroFilter",
    "PalmPose",
    "PoseConfig",
    "SO3OneEuroFilter",
    "SelectionConfig",
    "SyntheticSource",
    "TrackerConfig",
    "TrackingStream",
    "Trajectory",
    "VideoFileSource",
    "WebcamSource",
    "WorkspaceMapping",
    "estimate_palm_pose",
    "finger_flexion",
    "hand_scale_for_depth",
    "iter_frames",
    "iter_samples",
    "make_detector",
    "open_source",
    "palm_facing_camera",
    "palm_rotation",
    "robot_openness",
    "scripted_trajectory",
    "synthesize_detection",
]
