"""Inverse response curves of reroom.hdr.linearize."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reroom.errors import ReroomError
from reroom.hdr.linearize import linearize, resolve_response, response_lut
from reroom.synth.camera_sim import apply_response


@pytest.mark.parametrize("name", ["gamma2.2", "srgb", "linear"])
def test_named_curves_invert_the_camera(name):
    lut = response_lut(name)
    assert lut.shape == (256,) and lut[0] == 0 and lut[-1] == pytest.approx(1.0)
    assert np.all(np.diff(lut) > 0)
    # Encoding the LUT's linear values gives back every level.
    levels = np.round(apply_response(lut, name) * 255)
    np.testing.assert_array_equal(levels, np.arange(256))


def test_auto_uses_scan_metadata_else_gamma22():
    np.testing.assert_allclose(
        response_lut("auto", {"reroom": {"response": "srgb"}}), response_lut("srgb")
    )
    np.testing.assert_allclose(response_lut("auto", {}), response_lut("gamma2.2"))
    np.testing.assert_allclose(response_lut(None, None), response_lut("gamma2.2"))
    assert resolve_response("auto", {"reroom": {"response": "linear"}}) == "linear"
    assert resolve_response("auto", {}) == "gamma2.2"


def test_custom_gamma_and_user_curves(tmp_path):
    np.testing.assert_allclose(response_lut("gamma1.8"), (np.arange(256) / 255) ** 1.8)
    curve = (np.arange(256) / 255.0) ** 2.0 * 1000.0  # any units: normalised to white = 1
    np.testing.assert_allclose(response_lut(curve), curve / 1000.0)
    (tmp_path / "c.json").write_text(json.dumps(curve.tolist()))
    np.save(tmp_path / "c.npy", curve)
    (tmp_path / "c.txt").write_text("\n".join(map(str, curve)))
    for name in ("c.json", "c.npy", "c.txt"):
        np.testing.assert_allclose(response_lut(tmp_path / name), curve / 1000.0)
        np.testing.assert_allclose(response_lut(str(tmp_path / name)), curve / 1000.0)


@pytest.mark.parametrize(
    "spec, match",
    [
        ("gamma-1", "gamma must be"),
        ("cubic", "unknown response"),
        ("/nope/curve.txt", "missing"),
        (np.arange(10), "256 values"),
        (np.r_[np.arange(255), 3.0], "non-decreasing"),
        (np.r_[np.arange(255), np.nan], "non-finite"),
    ],
)
def test_bad_curves_raise(spec, match):
    with pytest.raises(ReroomError, match=match):
        response_lut(spec)


def test_linearize_image():
    img = np.array([[[0, 128, 255]]], np.uint8)
    out = linearize(img, response_lut("linear"))
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0, 0], [0, 128 / 255, 1], rtol=1e-6)
    with pytest.raises(ValueError):
        linearize(img.astype(np.float32), response_lut("linear"))
