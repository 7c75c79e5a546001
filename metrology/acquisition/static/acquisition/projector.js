/* The projector page (docs/acquisition.md).
 *
 * Shows, pixel-exact, the pattern the server says (long-poll of GET projector/?after=SEQ), and
 * confirms each one (POST projector/shown/) after the frame that paints it: drawn, then two
 * requestAnimationFrame callbacks (the first runs before the paint of the drawn frame, the
 * second after it). The canvas has one canvas pixel per device pixel (CSS size x devicePixelRatio)
 * and images are drawn at their own size at the top-left corner: no scaling, no smoothing.
 * Click (or press f) to go full screen; t shows the test pattern. With data-mode="webcam" the page
 * does not follow the server: webcam.js drives it (window.gcpsProjector).
 */
(function () {
  "use strict";
  var root = document.getElementById("projector");
  var canvas = document.getElementById("projector-canvas");
  var ctx = canvas.getContext("2d", { alpha: false });
  var stateUrl = root.dataset.stateUrl;
  var shownUrl = root.dataset.shownUrl;
  var frameUrl = root.dataset.frameUrl;
  var csrf = root.dataset.csrf;
  var handled = 0; // last sequence number drawn
  var current = { kind: "test", frame: -1, acquisition: null };
  var bitmaps = new Map();
  var status = "connecting";

  // what the test pattern's last line says; data-status on the page holds it too
  function setStatus(text) {
    if (text === status) return;
    status = text;
    root.dataset.status = text;
    if (current.kind === "test") draw(current);
  }

  function sleep(ms) { return new Promise(function (r) { setTimeout(r, ms); }); }

  function fitCanvas() {
    var dpr = window.devicePixelRatio || 1;
    var w = Math.round(window.innerWidth * dpr);
    var h = Math.round(window.innerHeight * dpr);
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
    }
    canvas.style.width = w / dpr + "px";
    canvas.style.height = h / dpr + "px";
    ctx.imageSmoothingEnabled = false;
    return dpr;
  }

  function fill(value) {
    ctx.fillStyle = value;
    ctx.fillRect(0, 0, canvas.width, canvas.height);
  }

  function drawTest() {
    var w = canvas.width, h = canvas.height, dpr = window.devicePixelRatio || 1;
    var img = ctx.createImageData(w, h), d = img.data;
    for (var y = 0; y < h; y++) {
      for (var x = 0; x < w; x++) {
        var v = 0;
        if (x === 0 || y === 0 || x === w - 1 || y === h - 1) v = 255; // one-pixel white border
        else if (x < 128 && y < 128) v = ((x + y) & 1) ? 255 : 0; // one-pixel checkerboard
        else if (x >= w - 128 && y < 128) v = (x & 1) ? 255 : 0; // one-pixel columns
        else if (x < 128 && y >= h - 128) v = (y & 1) ? 255 : 0; // one-pixel rows
        var i = 4 * (y * w + x);
        d[i] = d[i + 1] = d[i + 2] = v;
        d[i + 3] = 255;
      }
    }
    ctx.putImageData(img, 0, 0);
    ctx.fillStyle = "#fff";
    ctx.font = Math.round(16 * dpr) + "px sans-serif";
    var lines = [
      "GCPS projector · rig " + root.dataset.rig + " (" + root.dataset.rigName + ")",
      "canvas " + w + " x " + h + " device pixels, devicePixelRatio " + dpr,
      "pixel-exact when the checkerboard (top left), columns (top right) and rows (bottom left) show no grey or moire",
      "click or press f for full screen · status: " + status,
    ];
    for (var k = 0; k < lines.length; k++) ctx.fillText(lines[k], 160, 180 + k * 24 * dpr);
  }

  async function bitmapFor(acquisition, frame) {
    var url = frameUrl.replace("{acquisition}", acquisition).replace("{frame}", frame);
    if (bitmaps.has(url)) return bitmaps.get(url);
    var response = await fetch(url, { credentials: "same-origin" });
    if (!response.ok) throw new Error("frame " + frame + ": HTTP " + response.status);
    var blob = await response.blob();
    var bitmap = await createImageBitmap(blob, { colorSpaceConversion: "none", premultiplyAlpha: "none" });
    if (bitmaps.size > 64) bitmaps.clear();
    bitmaps.set(url, bitmap);
    return bitmap;
  }

  async function draw(state) {
    fitCanvas();
    var size = null;
    if (state.kind === "frame") {
      var bitmap = await bitmapFor(state.acquisition, state.frame);
      fill("#000");
      ctx.drawImage(bitmap, 0, 0); // its own size: one image pixel per device pixel
      size = [bitmap.width, bitmap.height];
    } else if (state.kind === "white") fill("#fff");
    else if (state.kind === "black" || state.kind === "blank") fill("#000");
    else drawTest();
    current = state;
    return size;
  }

  function afterPaint() {
    return new Promise(function (resolve) {
      requestAnimationFrame(function () { requestAnimationFrame(function () { resolve(); }); });
    });
  }

  async function confirm(state, size) {
    var dpr = window.devicePixelRatio || 1;
    var screen = {
      css_width: window.innerWidth, css_height: window.innerHeight, device_pixel_ratio: dpr,
      canvas_width: canvas.width, canvas_height: canvas.height,
      image_width: size ? size[0] : null, image_height: size ? size[1] : null,
      fits: size ? size[0] <= canvas.width && size[1] <= canvas.height : true,
      fullscreen: !!document.fullscreenElement,
    };
    await fetch(shownUrl, {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json", "X-CSRFToken": csrf },
      body: JSON.stringify({ seq: state.seq, kind: state.kind, frame: state.frame, screen: screen }),
    });
    root.dataset.shownSeq = String(state.seq);
    root.dataset.shownKind = state.kind;
    root.dataset.shownFrame = String(state.frame);
  }

  async function loop() {
    for (;;) {
      try {
        // the first question is answered at once, so that an idle page says "connected" at once
        var wait = status === "connected" ? 20 : 0;
        var response = await fetch(stateUrl + "?page=1&wait=" + wait + "&after=" + handled, {
          credentials: "same-origin", cache: "no-store",
        });
        if (!response.ok) throw new Error("HTTP " + response.status);
        var state = await response.json();
        setStatus("connected"); // idle too: the server answered, whether or not there is a new pattern
        if (state.seq > handled) {
          var size = await draw(state);
          await afterPaint();
          await confirm(state, size);
          handled = state.seq;
        }
      } catch (err) {
        setStatus("retrying (" + err.message + ")");
        await sleep(1000);
      }
    }
  }

  function fullScreen() {
    if (!document.fullscreenElement && document.documentElement.requestFullscreen) {
      document.documentElement.requestFullscreen().catch(function () {});
    }
  }

  // the webcam mode (webcam.js) drives the page itself instead of following the server's state
  window.gcpsProjector = {
    show: async function (state) {
      var size = await draw(state);
      await afterPaint();
      return size;
    },
    setStatus: setStatus,
  };

  document.addEventListener("click", fullScreen);
  document.addEventListener("keydown", function (event) {
    if (event.key === "f") fullScreen();
    if (event.key === "t") draw({ kind: "test", frame: -1, seq: handled });
  });
  window.addEventListener("resize", function () { draw(current); });
  root.dataset.status = status;
  draw(current);
  if (root.dataset.mode !== "webcam") loop();
})();
