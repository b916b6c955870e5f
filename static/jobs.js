// Live progress of build jobs (admin jobs page, model page): polls GET /api/v1/jobs/{id}
// for every element with data-job-id whose job is still queued or running, updates its
// progress fields and reloads the page once the job has ended. Without JavaScript the page
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
        else window.location.reload();
      })
      .catch(function () { setTimeout(function () { poll(el); }, 3000); });
  }
  pending.forEach(poll);
})();
