// Keeps a shared view through the login: the part of a link after '#' (the viewer's camera,
// `#camera=…`) never reaches the server, so the redirect to /login loses it unless the page
// hands it on. The browser keeps the fragment across the redirect; on submit it is appended
// to the `next` path the server sends the user back to. The page works without it.
(function () {
  "use strict";
  var form = document.getElementById("login-form");
  var next = form && form.elements.namedItem("next");
  if (!next) return;
  form.addEventListener("submit", function () {
    var hash = window.location.hash;
    if (hash && next.value.indexOf("#") < 0) next.value += hash;
  });
})();
