/* The acquisition page: refreshes the per-frame checks table while the agent grabs (GET /api/acquisitions/{id}/). */
(function () {
  "use strict";
  var table = document.getElementById("frame-checks");
  if (!table || table.dataset.finished) return;
  function cell(text) { var td = document.createElement("td"); td.textContent = text; return td; }
  function fixed(value, digits) { return value === null || value === undefined ? "" : Number(value).toFixed(digits); }
  function render(frames) {
    var body = table.tBodies[0];
    body.textContent = "";
    frames.forEach(function (f) {
      var row = document.createElement("tr");
      var change = f.change_fraction === null || f.change_fraction === undefined ? "" :
        fixed(f.change_fraction, 3) + (f.expected_change === null || f.expected_change === undefined ? "" : " (" + fixed(f.expected_change, 3) + ")");
      [(f.camera ? "cam" + f.camera + "/" : "") + f.name + (f.ok === false ? " (refused)" : ""), "", String(f.regrabs || 0), fixed(f.saturated_fraction, 4),
       fixed(f.dark_fraction, 4), change, fixed(f.correlation, 4),
       (f.refused_reasons || []).concat(f.reasons || []).join("; ")].forEach(function (t) { row.appendChild(cell(t)); });
      body.appendChild(row);
    });
  }
  function tick() {
    fetch(table.dataset.url, { credentials: "same-origin", headers: { Accept: "application/json" } })
      .then(function (r) { return r.json(); })
      .then(function (a) {
        render(a.frames || []);
        if (a.status !== "done" && a.status !== "failed") setTimeout(tick, 800);
      })
      .catch(function () { setTimeout(tick, 2000); });
  }
  tick();
})();
