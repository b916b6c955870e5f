// Live preview for the content editor: renders the Markdown through the server's
// sanitiser (POST /api/v1/preview) while typing. The page works without it.
(function () {
  "use strict";
  var form = document.getElementById("edit-form");
  var body = document.getElementById("body");
  var preview = document.getElementById("preview");
  if (!form || !body || !preview || !window.fetch) return;
  var csrf = form.getAttribute("data-csrf");
  var timer = null;
  var seq = 0;
  function update() {
    var mine = ++seq;
    fetch("/api/v1/preview", {
      method: "POST",
      credentials: "same-origin",
      headers: { "Content-Type": "application/json", "X-CSRF-Token": csrf },
      body: JSON.stringify({ body: body.value })
    }).then(function (r) { return r.ok ? r.json() : null; })
      .then(function (j) { if (j && mine === seq) preview.innerHTML = j.html; })
      .catch(function () {});
  }
  body.addEventListener("input", function () {
    clearTimeout(timer);
    timer = setTimeout(update, 300);
  });
  if (!preview.innerHTML.trim()) update();
})();
