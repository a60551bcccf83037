"""The BVH header a raw capture keeps (`skeleton_header_text`) agrees with the BVH reader:
every file the reader takes gives a header with its skeleton, its frame time and no frames."""

import pytest

from capture import parse_bvh
from capture.rawcapture import skeleton_header_text

from .test_bvh_format import SMALL  # two joints, two frames


@pytest.mark.parametrize("variant", [
    pytest.param(lambda t: t, id="plain"),
    pytest.param(lambda t: t.replace("MOTION", "Motion"), id="keyword-capitalised"),
    pytest.param(lambda t: t.replace("MOTION", "motion").replace("\n", "\r\n"),
                 id="keyword-lower-crlf"),
    pytest.param(lambda t: t.replace("}\nMOTION", "}MOTION"), id="brace-before-keyword"),
    pytest.param(lambda t: t.replace("Frame Time:", "FrameTime:"), id="frametime-one-word"),
])
def test_header_keeps_skeleton_and_frame_time_without_frames(variant):
    text = variant(SMALL)
    whole = parse_bvh(text, unit="cm")
    assert whole.motion.num_frames == 2  # the reader takes the variant
    header = parse_bvh(skeleton_header_text(text), unit="cm")
    assert header.motion.num_frames == 0
    assert header.motion.frame_time == whole.motion.frame_time == pytest.approx(0.0333333)
    assert header.skeleton.names == whole.skeleton.names
    assert header.skeleton.channels == whole.skeleton.channels
    assert (header.skeleton.offsets == whole.skeleton.offsets).all()
    assert (header.skeleton.end_sites == whole.skeleton.end_sites).all()
