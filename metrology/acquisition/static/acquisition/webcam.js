/* Zero-install webcam mode of the projector page (docs/acquisition.md): the page is the rig's
 * capture agent. It registers with the server (the agent protocol, session-authenticated), takes
 * queued acquisitions, shows each pattern itself (window.gcpsProjector from projector.js), grabs a
 * webcam frame per pattern through getUserMedia, and uploads the stack as a zip of PNGs.
 *
 * Frame choice: after a pattern is on screen, wait until the camera image has changed from the
 * previous grabbed frame, then the settle time, then take the next new video frame. Order: black,
 * white, black, then the codec's frames. The white frame has changed when at least MIN_LIT of all
 * the pixels brightened by more than CHANGE_GREY levels; from then on the change is counted over
 * the pixels lit at this exposure (white - black >= LIT_GREY): at least MIN_CHANGE of them by more
 * than CHANGE_GREY levels. (Counted over all the pixels, a short exposure of a bracket, which sees
 * only the bright part of the scene, would wait for ever on the patterns that change a small part
 * of it.) Per frame the page reports the saturated and dark fractions and the change (a fraction of
 * the lit pixels); the white frame the lit fraction.
 *
 * Exposure: an acquisition that asks for one exposure (exposure_ms) or several (exposures, a list
 * of ms: a multi-exposure capture, docs/exposures.md) needs a camera whose track offers a manual
 * exposureTime (getCapabilities()); the page sets each one with applyConstraints (exposureTime in
 * the Media Capture Image spec's units of 100 us), acquires the sequence once per exposure, and
 * uploads exposures.json with exp0/, exp1/, ... Without that capability, for a time outside the
 * camera's range, for exposures "auto" (the automatic bracket is the agent's), or when the white
 * frame does not brighten from one exposure to the next (a camera that takes the setting without
 * applying it), it fails the acquisition saying so: it never captures one exposure in their place.
 */
(function () {
  "use strict";
  var root = document.getElementById("projector");
  var video = document.getElementById("webcam-video");
  var P = window.gcpsProjector;
  var csrf = root.dataset.csrf;
  var settleMs = Number(root.dataset.settleMs || 300);
  var CHANGE_GREY = 24, LIT_GREY = 2 * CHANGE_GREY, MIN_CHANGE = 0.08, MIN_LIT = 0.01;
  var CHANGE_TIMEOUT_MS = 8000, MAX_GRABS = 3;
  var session = null, heartbeat = null, cameraLabel = "browser-webcam";

  function sleep(ms) { return new Promise(function (r) { setTimeout(r, ms); }); }
  function url(template, id) { return template.replace("{id}", String(id)); }

  async function call(address, body) {
    var response = await fetch(address, {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json", "X-CSRFToken": csrf },
      body: JSON.stringify(body),
    });
    if (response.status === 204) return null;
    var data = await response.json().catch(function () { return {}; });
    if (!response.ok) throw new Error(data.error || "HTTP " + response.status);
    return data;
  }

  function nextVideoFrame() {
    // the next frame the camera delivers (or 100 ms, where requestVideoFrameCallback is missing or idle)
    return new Promise(function (resolve) {
      if (video.requestVideoFrameCallback) video.requestVideoFrameCallback(function () { resolve(); });
      setTimeout(resolve, 100);
    });
  }

  var grabCanvas = document.createElement("canvas");
  var grabCtx = grabCanvas.getContext("2d", { willReadFrequently: true });

  function greyFrame() {
    var w = video.videoWidth, h = video.videoHeight;
    if (grabCanvas.width !== w || grabCanvas.height !== h) { grabCanvas.width = w; grabCanvas.height = h; }
    grabCtx.drawImage(video, 0, 0);
    var rgba = grabCtx.getImageData(0, 0, w, h).data;
    var grey = new Uint8Array(w * h);
    for (var i = 0, j = 0; i < grey.length; i++, j += 4) {
      grey[i] = Math.round(0.299 * rgba[j] + 0.587 * rgba[j + 1] + 0.114 * rgba[j + 2]);
    }
    return { width: w, height: h, data: grey };
  }

  // the fraction of the pixels (of those where lit is non-zero, when given) that changed by more than CHANGE_GREY
  function changeFraction(a, b, lit) {
    var n = 0, m = 0;
    for (var i = 0; i < a.data.length; i++) {
      if (lit && !lit[i]) continue;
      m++;
      if (Math.abs(a.data[i] - b.data[i]) > CHANGE_GREY) n++;
    }
    return m ? n / m : 0;
  }

  // the pixels the projector lights at this exposure (1 where white - black >= LIT_GREY) and their fraction
  function litPixels(white, black) {
    var lit = new Uint8Array(white.data.length), n = 0;
    for (var i = 0; i < lit.length; i++) {
      if (white.data[i] - black.data[i] >= LIT_GREY) { lit[i] = 1; n++; }
    }
    return { mask: lit, fraction: n / lit.length };
  }

  function stats(frame) {
    var sat = 0, dark = 0, sum = 0;
    for (var i = 0; i < frame.data.length; i++) {
      var v = frame.data[i];
      if (v >= 255) sat++;
      if (v <= 5) dark++;
      sum += v;
    }
    var n = frame.data.length;
    return { saturated_fraction: sat / n, dark_fraction: dark / n, mean_grey: sum / n };
  }

  // the frame after the camera image changed from previous (at least minChange of the pixels where lit
  // is non-zero, or of all of them), the settle time and a new video frame; previous null: no change awaited
  async function grabAfterChange(previous, lit, minChange) {
    var start = performance.now();
    var changed = null;
    if (previous) {
      for (;;) {
        await nextVideoFrame();
        changed = changeFraction(greyFrame(), previous, lit);
        if (changed >= minChange) break;
        if (performance.now() - start > CHANGE_TIMEOUT_MS) return { frame: null, change: changed };
      }
    }
    await sleep(settleMs);
    await nextVideoFrame();
    var frame = greyFrame();
    return { frame: frame, change: previous ? changeFraction(frame, previous, lit) : null };
  }

  function pngOf(frame) {
    var canvas = document.createElement("canvas");
    canvas.width = frame.width; canvas.height = frame.height;
    var ctx = canvas.getContext("2d");
    var image = ctx.createImageData(frame.width, frame.height);
    for (var i = 0, j = 0; i < frame.data.length; i++, j += 4) {
      image.data[j] = image.data[j + 1] = image.data[j + 2] = frame.data[i];
      image.data[j + 3] = 255;
    }
    ctx.putImageData(image, 0, 0);
    return new Promise(function (resolve) { canvas.toBlob(resolve, "image/png"); })
      .then(function (blob) { return blob.arrayBuffer(); })
      .then(function (buffer) { return new Uint8Array(buffer); });
  }

  // a zip without compression ("stored"), enough for PNGs
  var CRC = (function () {
    var table = new Uint32Array(256);
    for (var n = 0; n < 256; n++) {
      var c = n;
      for (var k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
      table[n] = c >>> 0;
    }
    return table;
  })();
  function crc32(bytes) {
    var c = 0xffffffff;
    for (var i = 0; i < bytes.length; i++) c = CRC[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
    return (c ^ 0xffffffff) >>> 0;
  }
  function zip(files) {
    var parts = [], central = [], offset = 0;
    files.forEach(function (file) {
      var name = new TextEncoder().encode(file.name), crc = crc32(file.data), size = file.data.length;
      var local = new DataView(new ArrayBuffer(30));
      local.setUint32(0, 0x04034b50, true); local.setUint16(4, 20, true); local.setUint32(14, crc, true);
      local.setUint32(18, size, true); local.setUint32(22, size, true); local.setUint16(26, name.length, true);
      parts.push(new Uint8Array(local.buffer), name, file.data);
      var entry = new DataView(new ArrayBuffer(46));
      entry.setUint32(0, 0x02014b50, true); entry.setUint16(4, 20, true); entry.setUint16(6, 20, true);
      entry.setUint32(16, crc, true); entry.setUint32(20, size, true); entry.setUint32(24, size, true);
      entry.setUint16(28, name.length, true); entry.setUint32(42, offset, true);
      central.push(new Uint8Array(entry.buffer), name);
      offset += 30 + name.length + size;
    });
    var centralSize = central.reduce(function (s, p) { return s + p.length; }, 0);
    var end = new DataView(new ArrayBuffer(22));
    end.setUint32(0, 0x06054b50, true); end.setUint16(8, files.length, true); end.setUint16(10, files.length, true);
    end.setUint32(12, centralSize, true); end.setUint32(16, offset, true);
    return new Blob(parts.concat(central, [new Uint8Array(end.buffer)]), { type: "application/zip" });
  }

  // The exposure times (ms) the acquisition asks for: null (the webcam's own exposure), or a list
  // (one entry for exposure_ms). Refuses what the page cannot do, with the reason.
  function requestedExposures(acquisition) {
    if (acquisition.exposures === "auto") {
      throw new Error("exposures \"auto\": the webcam page does not bracket automatically; request exposure " +
                      "times in ms (e.g. [1, 10, 100]) or run gcps agent, which brackets");
    }
    if (Array.isArray(acquisition.exposures)) return acquisition.exposures.map(Number);
    if (acquisition.exposure_ms !== null && acquisition.exposure_ms !== undefined) return [Number(acquisition.exposure_ms)];
    return null;
  }

  // Check that the track can take every exposure time (ms) manually; returns its range (100 us units).
  function manualExposureRange(track, times) {
    var caps = track && track.getCapabilities ? track.getCapabilities() : {};
    var modes = caps.exposureMode || [];
    if (!caps.exposureTime || modes.indexOf("manual") < 0) {
      throw new Error("the camera cannot set its exposure (" + cameraLabel + " offers no manual exposureTime " +
                      "among its capabilities), so it cannot capture the requested exposure(s) " + times.join(", ") +
                      " ms: use a webcam whose exposure the browser can set, or gcps agent --camera opencv:...");
    }
    var range = caps.exposureTime;
    times.forEach(function (ms) {
      if (ms * 10 < range.min || ms * 10 > range.max) {
        throw new Error("the camera's exposure time ranges over " + range.min / 10 + " to " + range.max / 10 +
                        " ms; exposure " + ms + " ms is outside it");
      }
    });
    return range;
  }

  // Set the exposure (ms) and return what the track reports using (ms), after the settle time.
  async function setExposure(track, ms) {
    await track.applyConstraints({ advanced: [{ exposureMode: "manual", exposureTime: ms * 10 }] });
    var settings = track.getSettings ? track.getSettings() : {};
    var used = settings.exposureTime ? settings.exposureTime / 10 : ms;
    if (settings.exposureMode && settings.exposureMode !== "manual") {
      throw new Error("the camera did not switch to manual exposure (exposureMode " + settings.exposureMode + ")");
    }
    await sleep(settleMs);
    for (var k = 0; k < 3; k++) await nextVideoFrame();  // frames exposed before the change
    return used;
  }

  // Before a multi-exposure capture: the white frame grabbed at each exposure must brighten from one
  // exposure to the next (1.5x or more apart) by more than 10 % (and 2 grey levels) over the pixels
  // saturated in neither; a camera that accepts exposureTime without applying it would give
  // exposures that all look alike, so the acquisition fails instead.
  async function checkExposuresApply(track, times, id) {
    await P.show({ kind: "white", frame: -1, acquisition: id, seq: 0 });
    var whites = [];
    for (var k = 0; k < times.length; k++) {
      await setExposure(track, times[k]);
      whites.push((await grabAfterChange(null, null, 0)).frame);
    }
    for (var i = 0; i + 1 < times.length; i++) {
      if (times[i + 1] < 1.5 * times[i]) continue;
      var a = whites[i].data, b = whites[i + 1].data, n = 0, sumA = 0, sumB = 0;
      for (var j = 0; j < a.length; j++) {
        if (a[j] < 255 && b[j] < 255) { n++; sumA += a[j]; sumB += b[j]; }
      }
      if (n < 0.01 * a.length) continue;  // saturated nearly everywhere: nothing to compare
      var meanA = sumA / n, meanB = sumB / n;
      if (meanB - meanA <= Math.max(2, 0.1 * meanA)) {
        throw new Error("the camera's image did not brighten from exposure " + times[i] + " ms to " + times[i + 1] +
                        " ms (white frame, mean grey " + meanA.toFixed(1) + " -> " + meanB.toFixed(1) + "): it does " +
                        "not apply the exposure time it offers, so the exposures would all look alike");
      }
    }
  }

  // One pass of the sequence (black, white, black, the codec's frames); pushes the checks, returns the frames.
  async function grabSequence(acquisition, checks, exposure, progress) {
    var sequence = [{ kind: "black", name: "black" }, { kind: "white", name: "white" }, { kind: "black", name: "black" }];
    acquisition.frame_names.forEach(function (name, k) { sequence.push({ kind: "frame", frame: k, name: name }); });
    var previous = null, frames = [], black = null, lit = null;
    var at = exposure === null ? "" : " at exposure " + exposure + " ms";
    for (var s = 0; s < sequence.length; s++) {
      var item = sequence[s], result = null;
      // the white frame: a change on MIN_LIT of all the pixels; then MIN_CHANGE of the lit pixels
      var minChange = lit ? MIN_CHANGE : MIN_LIT;
      await P.show({ kind: item.kind, frame: item.frame === undefined ? -1 : item.frame, acquisition: acquisition.id, seq: 0 });
      for (var attempt = 1; attempt <= MAX_GRABS; attempt++) {
        result = await grabAfterChange(previous, lit ? lit.mask : null, minChange);
        if (result.frame) break;
      }
      if (!result.frame) {
        throw new Error("the camera image did not change after showing " + item.name + at + " (" + MAX_GRABS +
                        " tries): is the webcam looking at the projection?");
      }
      var check = Object.assign({ name: item.name, kind: item.kind, frame: item.frame === undefined ? -1 : item.frame,
                                  change_fraction: result.change, regrabs: 0, refused_reasons: [], ok: true },
                                stats(result.frame));
      if (exposure !== null) check.exposure_ms = exposure;
      if (item.kind === "black" && black === null) black = result.frame;
      if (item.kind === "white") {
        lit = litPixels(result.frame, black);
        check.lit_fraction = lit.fraction;
        if (lit.fraction < MIN_LIT) {
          throw new Error("the projector lights " + (100 * lit.fraction).toFixed(2) + " % of the camera's pixels" + at +
                          " (white - black >= " + LIT_GREY + " grey levels; at least " + 100 * MIN_LIT + " % needed): " +
                          "is the webcam looking at the projection, is the exposure long enough?");
        }
      }
      checks.push(check);
      previous = result.frame;
      if (item.kind === "frame") frames.push({ name: item.name + ".png", frame: result.frame });
      await progress((s + 1) / sequence.length, "grabbed " + item.name);
    }
    return frames;
  }

  async function acquire(acquisition) {
    var id = acquisition.id, checks = [];
    var times = requestedExposures(acquisition);
    // ask for the rig's camera size: the server refuses frames of another size
    var size = { width: { ideal: Number(root.dataset.cameraWidth) }, height: { ideal: Number(root.dataset.cameraHeight) } };
    var stream = await navigator.mediaDevices.getUserMedia({ video: size, audio: false });
    try {
      var track = stream.getVideoTracks()[0];
      cameraLabel = "browser:" + (track && track.label ? track.label : "webcam");
      if (times !== null) manualExposureRange(track, times);
      video.srcObject = stream;
      await video.play();
      if (video.videoWidth !== Number(root.dataset.cameraWidth) || video.videoHeight !== Number(root.dataset.cameraHeight)) {
        throw new Error("the webcam gives " + video.videoWidth + "x" + video.videoHeight + " frames, the rig's camera is " +
                        root.dataset.cameraWidth + "x" + root.dataset.cameraHeight + ": set the rig's width_px and height_px to the webcam's");
      }
      var multi = Array.isArray(acquisition.exposures), passes = times === null ? [null] : times;
      if (multi) await checkExposuresApply(track, times, id);
      var files = [], used = [];
      for (var e = 0; e < passes.length; e++) {
        var exposure = passes[e] === null ? null : await setExposure(track, passes[e]);
        used.push(exposure);
        var frames = await grabSequence(acquisition, checks, exposure, function (done, phase) {
          var label = multi ? "exposure " + (e + 1) + "/" + passes.length + ": " + phase : phase;
          return call(url(root.dataset.progressUrl, id), {
            session: session, percent: Math.round(5 + 85 * (e + done) / passes.length), phase: label.slice(0, 64),
            frames: checks,
          });
        });
        var folder = multi ? "exp" + e + "/" : "";
        for (var f = 0; f < frames.length; f++) {
          files.push({ name: folder + frames[f].name, data: await pngOf(frames[f].frame) });
        }
      }
      await P.show({ kind: "black", frame: -1, seq: 0 });
      if (multi) {
        var manifest = { format: "gcps-exposures/1", exposures: used.map(function (ms, k) {
          return { name: "exp" + k, exposure_us: ms * 1000 };
        }) };
        files.unshift({ name: "exposures.json", data: new TextEncoder().encode(JSON.stringify(manifest)) });
      }
      var form = new FormData();
      form.append("session", session);
      form.append("camera", cameraLabel);
      if (used[0] !== null) form.append("exposure_ms", String(used[0]));
      form.append("frames", JSON.stringify(checks));
      form.append("file", zip(files), "acquisition-" + id + ".zip");
      var response = await fetch(url(root.dataset.uploadUrl, id), {
        method: "POST", credentials: "same-origin", headers: { "X-CSRFToken": csrf }, body: form,
      });
      var body = await response.json().catch(function () { return {}; });
      if (!response.ok) throw new Error(body.error || "upload: HTTP " + response.status);
      root.dataset.lastCapture = String(body.capture);
    } finally {
      stream.getTracks().forEach(function (t) { t.stop(); });
      video.srcObject = null;
    }
  }

  async function main() {
    for (;;) {
      try {
        var registered = await call(root.dataset.registerUrl, { camera: cameraLabel, name: "projector page (webcam)" });
        session = registered.session;
        heartbeat = setInterval(function () {
          call(root.dataset.heartbeatUrl, { session: session }).catch(function () {});
        }, 1000 * registered.heartbeat_seconds);
        break;
      } catch (err) {
        P.setStatus("webcam agent: " + err.message);
        await sleep(3000);
      }
    }
    root.dataset.agentSession = session;
    P.setStatus("webcam agent ready");
    window.addEventListener("pagehide", function () {
      var data = new Blob([JSON.stringify({ session: session, reason: "the webcam page was closed" })],
                          { type: "application/json" });
      navigator.sendBeacon && fetch(root.dataset.disconnectUrl, {
        method: "POST", keepalive: true, credentials: "same-origin",
        headers: { "Content-Type": "application/json", "X-CSRFToken": csrf }, body: data,
      });
    });
    for (;;) {
      var acquisition = null;
      try {
        acquisition = await call(root.dataset.takeUrl, { session: session });
      } catch (err) {
        P.setStatus("webcam agent: " + err.message);
        await sleep(3000);
        continue;
      }
      if (!acquisition) { await sleep(1000); continue; }
      try {
        await acquire(acquisition);
      } catch (err) {
        await call(url(root.dataset.failUrl, acquisition.id), { session: session, reason: "webcam page: " + err.message })
          .catch(function () {});
        await P.show({ kind: "test", frame: -1, seq: 0 });
        P.setStatus("last acquisition failed: " + err.message);
      }
    }
  }

  main();
})();
