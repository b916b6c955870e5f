// Upload progress for the scan forms of the jobs page: the form is sent with XMLHttpRequest
// so its upload progress can be shown (multi-gigabyte scans take minutes). On success the
// browser follows the server's redirect (the new model's page); a refusal shows the server's
// message in the form, with everything typed kept. Without JavaScript the form posts as is.
(function () {
  "use strict";
  if (!window.XMLHttpRequest || !window.FormData) return;
  var forms = document.querySelectorAll("form[data-upload]");
  function mb(n) { return (n / 1048576).toFixed(1) + " MB"; }
  for (var i = 0; i < forms.length; i++) bind(forms[i]);
  function bind(form) {
    var bar = form.querySelector("progress[data-upload-progress]");
    var text = form.querySelector("[data-upload-status]");
    var message = form.querySelector("[data-upload-error]");
    form.addEventListener("submit", function (e) {
      e.preventDefault();
      var button = form.querySelector("button[type=submit]");
      if (button) button.disabled = true;
      if (message) { message.hidden = true; message.textContent = ""; message.removeAttribute("role"); }
      if (bar) { bar.hidden = false; bar.value = 0; bar.setAttribute("data-max-seen", "0"); }
      var xhr = new XMLHttpRequest();
      xhr.open("POST", form.action);
      xhr.upload.addEventListener("progress", function (ev) {
        if (!ev.lengthComputable) return;
        var pct = Math.round((ev.loaded / ev.total) * 1000) / 10;
        if (bar) {
          bar.value = pct;
          bar.setAttribute("data-max-seen", String(Math.max(pct, Number(bar.getAttribute("data-max-seen")))));
        }
        if (text) text.textContent = "Uploading: " + mb(ev.loaded) + " of " + mb(ev.total) + " (" + pct + " %)";
      });
      xhr.addEventListener("load", function () {
        if (xhr.status >= 200 && xhr.status < 300 && xhr.responseURL && xhr.responseURL !== form.action) {
          if (text) text.textContent = "Uploaded: the build starts.";
          window.location.assign(xhr.responseURL);
          return;
        }
        var doc = new DOMParser().parseFromString(xhr.responseText, "text/html");
        var alert = doc.querySelector("p.error[role=alert]");
        fail(alert ? alert.textContent : "The upload failed (HTTP " + xhr.status + ").");
      });
      xhr.addEventListener("error", function () { fail("The upload was interrupted: check the connection and try again."); });
      function fail(msg) {
        if (button) button.disabled = false;
        if (bar) bar.hidden = true;
        if (text) text.textContent = "";
        if (message) { message.textContent = msg; message.hidden = false; message.setAttribute("role", "alert"); }
      }
      xhr.send(new FormData(form));
    });
  }
})();
