// Live progress of build jobs (admin jobs page, model page): polls GET /api/v1/jobs/{id}
// for every element with data-job-id whose job is still queued or running, updates its
// progress fields and reloads the page once the job has ended — unless a form of the page
// holds something the person typed or picked (an upload being filled in or under way): then
// the row shows the job's end in place and the page stays. Without JavaScript the page
// refreshes itself (<meta http-equiv="refresh"> in <noscript>).
(function () {
  "use strict";
  if (!window.fetch) return;
  var active = { queued: true, running: true };
  var nodes = document.querySelectorAll("[data-job-id]");
  var pending = [];
  for (var i = 0; i < nodes.length; i++) {
    if (active[nodes[i].getAttribute("data-job-status")]) pending.push(nodes[i]);
  }
  if (!pending.length) return;
  // Whether a form field differs from what the page came with (a reload would lose it).
  function edited() {
    var fields = document.querySelectorAll("form input, form textarea, form select");
    for (var k = 0; k < fields.length; k++) {
      var f = fields[k];
      if (f.type === "hidden" || f.type === "submit" || f.type === "button") continue;
      if (f.type === "file") { if (f.files && f.files.length) return true; continue; }
      if (f.type === "checkbox" || f.type === "radio") { if (f.checked !== f.defaultChecked) return true; continue; }
      if (f.tagName === "SELECT") {
        for (var o = 0; o < f.options.length; o++) if (f.options[o].selected !== f.options[o].defaultSelected) return true;
        continue;
      }
      if (f.value !== f.defaultValue) return true;
    }
    return false;
  }
  function set(el, field, fn) {
    var f = el.querySelectorAll("[data-job-field='" + field + "']");
    for (var k = 0; k < f.length; k++) fn(f[k]);
  }
  function poll(el) {
    var id = el.getAttribute("data-job-id");
    fetch("/api/v1/jobs/" + encodeURIComponent(id), { credentials: "same-origin" })
      .then(function (r) { return r.ok ? r.json() : null; })
      .then(function (j) {
        if (!j) { setTimeout(function () { poll(el); }, 3000); return; }
        var pct = (Math.round(j.percent * 10) / 10).toFixed(1);
        set(el, "status", function (f) { f.textContent = j.status; });
        set(el, "stage", function (f) {
          f.textContent = j.stage + (j.total > 0 ? " (" + j.done + " / " + j.total + ")" : "");
        });
        set(el, "percent", function (f) { f.textContent = pct + " %"; });
        set(el, "progress", function (f) { f.value = j.percent; f.textContent = pct + " %"; });
        el.setAttribute("data-job-status", j.status);
        if (active[j.status]) setTimeout(function () { poll(el); }, 1000);
        else if (!edited()) window.location.reload();
      })
      .catch(function () { setTimeout(function () { poll(el); }, 3000); });
  }
  pending.forEach(poll);
})();
