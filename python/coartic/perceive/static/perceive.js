// Trial pages: each stimulus is played with its own button (no controls: no scrubbing); the answer
// buttons open once every required video has played to its end; without `replay` a video plays once.
(function () {
  var form = document.getElementById("answer-form");
  if (!form) { return; }
  var replay = form.dataset.replay === "yes";
  var videos = Array.prototype.slice.call(form.querySelectorAll("video"));
  var played = new Set();
  var endedAt = null;
  function openAnswers() {
    var required = videos.filter(function (v) { return v.dataset.required === "yes"; });
    if (required.every(function (v) { return played.has(v); })) {
      endedAt = performance.now();
      form.querySelectorAll(".answer").forEach(function (el) { el.disabled = false; });
      var text = document.getElementById("text");
      if (text) { text.focus(); }
    }
  }
  videos.forEach(function (video) {
    var button = video.parentElement.querySelector("button.play");
    button.addEventListener("click", function () {
      videos.forEach(function (other) { if (other !== video) { other.pause(); } });
      video.currentTime = 0;
      var p = video.play();
      if (p && p.catch) { p.catch(function (err) { button.textContent = "Cannot play: " + err.name; }); }
      button.disabled = true;
    });
    video.addEventListener("ended", function () {
      played.add(video);
      if (replay) { button.disabled = false; button.textContent = "Play again"; }
      openAnswers();
    });
    video.addEventListener("error", function () {
      button.textContent = "This video cannot play in this browser";
      button.disabled = true;
    });
  });
  form.querySelectorAll("input[type=range]").forEach(function (r) {
    r.addEventListener("input", function () { r.parentElement.querySelector("output").value = r.value; });
  });
  form.addEventListener("submit", function (ev) {
    if (form.dataset.sent === "yes") { ev.preventDefault(); return; }
    form.dataset.sent = "yes";
    if (endedAt !== null) { document.getElementById("rt_ms").value = Math.round(performance.now() - endedAt); }
  });
})();
