// Scan uploads of the jobs page, resumable: the form's files (a scan with the files it refers
// to, picked together or as their folder, or one .zip) go up through an upload session of
// the API (/api/v1/uploads) in chunks, each appended at the offset the server holds. A dropped
// connection or a restarted server costs at most one chunk: the upload asks the server what
// it holds and goes on from there, and picking the same files again after closing the page
// resumes the same session. Progress is shown as it goes; once every byte is in, the session
// is finished into the model's build and the browser opens the model's page. A refusal shows
// the server's message in the form, with everything typed kept. Without JavaScript the form
// posts as a plain multipart upload.
(function () {
  "use strict";
  if (!window.fetch || !window.XMLHttpRequest || !window.localStorage || !window.Blob) return;
  var STORE = "meshwiki-upload:";
  var MAX_RETRIES = 8;
  var forms = document.querySelectorAll("form[data-upload]");
  for (var i = 0; i < forms.length; i++) bind(forms[i]);

  // The form's build options (empty fields: the server's defaults), as POST .../finish takes them.
  function buildOptions(form) {
    var build = {};
    var simplifier = form.querySelector("[name=simplifier]");
    if (simplifier && simplifier.value) build.simplifier = simplifier.value;
    var vertexOrder = form.querySelector("[name=vertex_order]");
    if (vertexOrder && vertexOrder.value) build.vertex_order = vertexOrder.value;
    ["patch_triangles", "texture_quality", "texture_spread"].forEach(function (name) {
      var input = form.querySelector("[name=" + name + "]");
      if (input && input.value.trim() !== "") build[name] = Number(input.value);
    });
    var normalMaps = form.querySelector("[name=normal_maps]");
    if (normalMaps && normalMaps.checked) build.normal_maps = true;
    return build;
  }

  function mb(n) { return (n / 1048576).toFixed(1) + " MB"; }
  function sleep(ms) { return new Promise(function (r) { setTimeout(r, ms); }); }

  /** The form's files with the relative paths the scan refers to them by. */
  function pickedFiles(form) {
    var out = [];
    var inputs = form.querySelectorAll("input[type=file]");
    for (var k = 0; k < inputs.length; k++) {
      var list = inputs[k].files || [];
      for (var j = 0; j < list.length; j++) {
        var f = list[j];
        out.push({ file: f, path: f.webkitRelativePath || f.name });
      }
    }
    return out;
  }

  /** The key under which this pick's session is remembered (same files, same session). */
  function fingerprint(picked, model) {
    return STORE + JSON.stringify([model || "", picked.map(function (p) { return [p.path, p.file.size, p.file.lastModified]; })]);
  }

  function errorOf(xhrOrRes, text) {
    try {
      var e = JSON.parse(text);
      if (e && e.error) return e.error;
    } catch (_) { /* not JSON */ }
    return "the server answered HTTP " + xhrOrRes.status;
  }

  function bind(form) {
    var bar = form.querySelector("progress[data-upload-progress]");
    var text = form.querySelector("[data-upload-status]");
    var message = form.querySelector("[data-upload-error]");
    var button = form.querySelector("button[type=submit]");
    var csrf = (form.querySelector("input[name=csrf_token]") || {}).value || "";
    var cancel = document.createElement("button");
    cancel.type = "button";
    cancel.className = "secondary";
    cancel.textContent = "Cancel upload";
    cancel.hidden = true;
    if (button) button.after(cancel);
    var current = null; // {session, xhr, cancelled}

    function say(s) { if (text) text.textContent = s; }
    function fail(msg) {
      if (button) button.disabled = false;
      cancel.hidden = true;
      if (bar) bar.hidden = true;
      say("");
      if (message) { message.textContent = msg; message.hidden = false; message.setAttribute("role", "alert"); }
    }
    function api(method, url, body) {
      var headers = { "X-CSRF-Token": csrf, Accept: "application/json" };
      if (body !== undefined) headers["Content-Type"] = "application/json";
      return fetch(url, { method: method, headers: headers, credentials: "same-origin", body: body === undefined ? undefined : JSON.stringify(body) });
    }

    cancel.addEventListener("click", function () {
      if (!current) return;
      current.cancelled = true;
      if (current.xhr) current.xhr.abort();
      var s = current.session;
      if (s) {
        localStorage.removeItem(current.key);
        api("DELETE", "/api/v1/uploads/" + s.id).catch(function () {});
      }
      fail("Upload cancelled.");
    });

    form.addEventListener("submit", function (e) {
      var picked = pickedFiles(form);
      if (picked.length === 0) return; // the server says what is missing
      e.preventDefault();
      if (button) button.disabled = true;
      if (message) { message.hidden = true; message.textContent = ""; message.removeAttribute("role"); }
      if (bar) { bar.hidden = false; bar.value = 0; bar.setAttribute("data-max-seen", "0"); }
      cancel.hidden = false;
      var model = (form.querySelector("input[name=model]") || {}).value || "";
      var job = { key: fingerprint(picked, model), cancelled: false, session: null, xhr: null };
      current = job;
      run(job, picked, model).catch(function (err) {
        if (!job.cancelled) fail(err.message || String(err));
      });
    });

    /** Opens (or finds again) the session of these files. */
    async function session(job, picked) {
      var known = localStorage.getItem(job.key);
      if (known) {
        var res = await api("GET", "/api/v1/uploads/" + encodeURIComponent(known));
        if (res.ok) {
          var s = await res.json();
          var same = s.files.length === picked.length && s.files.every(function (f, k) { return f.path === picked[k].path && f.size === picked[k].file.size; });
          if (same) return s;
        }
        localStorage.removeItem(job.key);
      }
      var created = await api("POST", "/api/v1/uploads", { files: picked.map(function (p) { return { path: p.path, size: p.file.size }; }) });
      var body = await created.text();
      if (created.status !== 201) throw new Error(errorOf(created, body));
      var fresh = JSON.parse(body);
      localStorage.setItem(job.key, fresh.id);
      return fresh;
    }

    /** PATCHes one chunk; resolves with the server's offset after it. */
    function send(job, index, offset, blob, onProgress) {
      return new Promise(function (resolve, reject) {
        var xhr = new XMLHttpRequest();
        job.xhr = xhr;
        xhr.open("PATCH", "/api/v1/uploads/" + job.session.id + "/files/" + index);
        xhr.setRequestHeader("X-CSRF-Token", csrf);
        xhr.setRequestHeader("Upload-Offset", String(offset));
        xhr.setRequestHeader("Content-Type", "application/offset+octet-stream");
        xhr.upload.addEventListener("progress", function (ev) { onProgress(ev.loaded); });
        xhr.addEventListener("load", function () {
          var held = Number(xhr.getResponseHeader("Upload-Offset"));
          if (xhr.status === 204 || (xhr.status === 409 && Number.isFinite(held) && xhr.getResponseHeader("Upload-Offset") !== null)) {
            resolve(held);
          } else if (xhr.status >= 500 || xhr.status === 409) {
            reject({ retry: true, message: errorOf(xhr, xhr.responseText) });
          } else {
            reject(new Error(errorOf(xhr, xhr.responseText)));
          }
        });
        xhr.addEventListener("error", function () { reject({ retry: true, message: "the connection was lost" }); });
        xhr.addEventListener("abort", function () { reject(new Error("Upload cancelled.")); });
        xhr.send(blob);
      });
    }

    async function run(job, picked, model) {
      say("Preparing the upload…");
      job.session = await session(job, picked);
      var s = job.session;
      var chunk = s.chunk_size || 8388608;
      var total = picked.reduce(function (a, p) { return a + p.file.size; }, 0);
      var held = s.files.map(function (f) { return f.received; });
      var resumed = held.reduce(function (a, b) { return a + b; }, 0);
      function show(extra) {
        var done = held.reduce(function (a, b) { return a + b; }, 0) + extra;
        var pct = total > 0 ? Math.round((done / total) * 1000) / 10 : 100;
        if (bar) {
          bar.value = pct;
          bar.setAttribute("data-max-seen", String(Math.max(pct, Number(bar.getAttribute("data-max-seen")))));
        }
        say("Uploading: " + mb(done) + " of " + mb(total) + " (" + pct + " %)" + (resumed > 0 ? ", resumed at " + mb(resumed) : ""));
      }
      show(0);
      for (var index = 0; index < picked.length; index++) {
        var file = picked[index].file;
        var retries = 0;
        while (held[index] < file.size) {
          if (job.cancelled) return;
          var from = held[index];
          try {
            held[index] = await send(job, index, from, file.slice(from, Math.min(file.size, from + chunk)), show);
            retries = 0;
            show(0);
          } catch (err) {
            if (!err || !err.retry || job.cancelled) throw err instanceof Error ? err : new Error(String(err && err.message));
            retries++;
            if (retries > MAX_RETRIES) throw new Error("The upload stopped (" + err.message + "). Pick the same files and upload again: it resumes where it stopped.");
            var wait = Math.min(30, Math.pow(2, retries - 1));
            say("Connection lost (" + err.message + "): retrying in " + wait + " s; the upload resumes where it stopped.");
            await sleep(wait * 1000);
            // Ask what arrived before going on.
            var res = await api("GET", "/api/v1/uploads/" + s.id).catch(function () { return null; });
            if (res && res.ok) held = (await res.json()).files.map(function (f) { return f.received; });
          }
        }
      }
      if (job.cancelled) return;
      say("Uploaded: starting the build…");
      var body = model ? { model: Number(model) } : {
        title: (form.querySelector("[name=title]") || {}).value || "",
        description: (form.querySelector("[name=description]") || {}).value || "",
      };
      body.build = buildOptions(form);
      var res = await api("POST", "/api/v1/uploads/" + s.id + "/finish", body);
      var answer = await res.text();
      if (res.status !== 202) {
        if (res.status === 404 || res.status === 413) localStorage.removeItem(job.key);
        throw new Error(errorOf(res, answer));
      }
      localStorage.removeItem(job.key);
      cancel.hidden = true;
      var built = JSON.parse(answer);
      say("Uploaded: the build starts.");
      window.location.assign("/models/" + built.model.id);
    }
  }
})();
