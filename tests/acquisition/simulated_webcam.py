"""A simulated webcam with a manual exposure time, for the projector page's webcam mode in a browser
(tests/acquisition/test_webcam.py).

Chromium's fake camera advertises ``exposureTime`` but ignores it, so it cannot show the page's
multi-exposure success path. :func:`init_script` is a Playwright init script that replaces
``navigator.mediaDevices.getUserMedia`` before the page's code runs: it answers with the video
track of a ``canvas.captureStream()`` whose ``getCapabilities()`` / ``getSettings()`` /
``applyConstraints()`` offer ``exposureMode: "manual"`` and ``exposureTime`` (in the Media Capture
Image draft's units of 100 us, as webcam.js assumes). It stands in for the camera hardware only (as
the agent's virtual camera does); the page's bracketing, capture and upload, and the server's
reading and measurement, are the code under test.

What the camera sees, at every video frame (``FPS`` a second): the region of the page's projector
canvas (``#projector-canvas``) ``SCALE * W`` x ``SCALE * H`` device pixels from ``ORIGIN``, reduced
``SCALE``:1 by the canvas's bilinear ``drawImage`` (at 2:1 the mean of each 2 x 2 block): ``P`` in
[0, 1]. That is a plane facing the projector, one camera pixel per 2 x 2 projector pixels. The
camera pixel's grey level is

    g = min(255, round(FULL_GREY * rho * (t / T_REF) * (AMBIENT + P)))

with ``t`` the exposure time set through ``applyConstraints`` (``T_REF`` before any is set), ``rho``
the scene's reflectance (:func:`reflectance`: a bright patch of 1 on a matte ramp from 0.1 down to
0.001, 1000:1) and ``AMBIENT`` ambient light that the exposure scales too. All three of the frame's
channels hold ``g``, so the page's grey conversion returns it exactly (a canvas's grey levels cross
``captureStream`` and the ``<video>`` element unchanged in Chromium 156).
"""

from __future__ import annotations

import json

import numpy as np

W, H = 160, 120  # the camera (SMALL_RIG's width_px x height_px)
SCALE = 2  # projector pixels per camera pixel, each way
ORIGIN = (352, 264)  # the projector pixel (x, y) at the camera's top-left corner (even: gray edges fall between pixels)
FULL_GREY = 230.0  # grey level of a white projector pixel on reflectance 1 at T_REF, without ambient light
T_REF_MS = 2.0  # the exposure at which FULL_GREY holds; the track's exposure before any is set
AMBIENT = 0.02  # ambient light, relative to the projector's white
PATCH = (56, 120)  # the bright patch's columns (40 % of the image): projector codes 58 to 74, across gray edges
FPS = 60
EXPOSURE_RANGE_100US = (1, 10000)  # 0.1 ms .. 1 s


def reflectance() -> np.ndarray:
    """``(H, W)`` float64 reflectance of the scene: 1 on the bright patch (the columns of ``PATCH``);
    elsewhere a matte ramp falling geometrically along the columns from 0.1 (column 0) to 0.001
    (column W - 1): 1000:1 overall."""
    columns = np.arange(W)
    rho = 0.1 * 0.01 ** (columns / (W - 1))
    rho = np.where((columns >= PATCH[0]) & (columns < PATCH[1]), 1.0, rho)
    return np.broadcast_to(rho, (H, W)).copy()


def grey(projected: np.ndarray, exposure_ms: float) -> np.ndarray:
    """The camera's grey levels (uint8, as the simulated camera computes them) for ``projected``, the
    ``(H, W)`` projector light in [0, 1] seen by each camera pixel, at ``exposure_ms``."""
    value = FULL_GREY * reflectance() * (exposure_ms / T_REF_MS) * (AMBIENT + projected)
    return np.minimum(255, np.floor(value + 0.5)).astype(np.uint8)  # JavaScript's Math.round


def init_script() -> str:
    """The JavaScript (a Playwright ``add_init_script``) that installs the simulated camera."""
    settings = {
        "width": W,
        "height": H,
        "scale": SCALE,
        "origin": list(ORIGIN),
        "fullGrey": FULL_GREY,
        "tRef100us": T_REF_MS * 10,
        "ambient": AMBIENT,
        "fps": FPS,
        "range": list(EXPOSURE_RANGE_100US),
        "reflectance": [round(float(r), 9) for r in reflectance().ravel()],
    }
    return _SCRIPT.replace("__SETTINGS__", json.dumps(settings))


_SCRIPT = """
(function () {
  "use strict";
  var S = __SETTINGS__;
  var rho = Float64Array.from(S.reflectance);
  navigator.mediaDevices.getUserMedia = async function () {
    var camera = document.createElement("canvas");
    camera.width = S.width; camera.height = S.height;
    var ctx = camera.getContext("2d", { willReadFrequently: true });
    var state = { exposureMode: "continuous", exposureTime: S.tRef100us };
    function draw() {
      var projector = document.getElementById("projector-canvas");
      ctx.imageSmoothingEnabled = true;
      ctx.imageSmoothingQuality = "low";  // bilinear: at 2:1 the mean of each 2 x 2 block
      ctx.fillStyle = "#000";
      ctx.fillRect(0, 0, S.width, S.height);
      if (projector) {
        ctx.drawImage(projector, S.origin[0], S.origin[1], S.scale * S.width, S.scale * S.height,
                      0, 0, S.width, S.height);
      }
      var image = ctx.getImageData(0, 0, S.width, S.height), d = image.data;
      var gain = S.fullGrey * state.exposureTime / S.tRef100us;
      for (var i = 0, j = 0; i < rho.length; i++, j += 4) {
        var g = Math.min(255, Math.round(gain * rho[i] * (S.ambient + d[j] / 255)));
        d[j] = d[j + 1] = d[j + 2] = g;
        d[j + 3] = 255;
      }
      ctx.putImageData(image, 0, 0);
    }
    draw();
    var stream = camera.captureStream(S.fps);
    var track = stream.getVideoTracks()[0];
    var timer = setInterval(function () {
      if (track.readyState === "ended") { clearInterval(timer); return; }
      draw();
    }, 1000 / S.fps);
    var ownCapabilities = track.getCapabilities.bind(track);
    Object.defineProperty(track, "label", { value: "simulated camera (tests/acquisition/simulated_webcam.py)" });
    track.getCapabilities = function () {
      return Object.assign({}, ownCapabilities(), {
        exposureMode: ["manual", "continuous"],
        exposureTime: { min: S.range[0], max: S.range[1], step: 1 },
      });
    };
    track.getSettings = function () {
      return { width: S.width, height: S.height, frameRate: S.fps,
               exposureMode: state.exposureMode, exposureTime: state.exposureTime };
    };
    track.applyConstraints = async function (constraints) {
      var sets = [constraints || {}].concat((constraints && constraints.advanced) || []);
      sets.forEach(function (set) {
        if (set.exposureMode !== undefined) state.exposureMode = set.exposureMode;
        if (set.exposureTime !== undefined) {
          var t = Math.round(Number(set.exposureTime));
          state.exposureTime = Math.min(S.range[1], Math.max(S.range[0], t));
        }
      });
    };
    return stream;
  };
})();
"""
