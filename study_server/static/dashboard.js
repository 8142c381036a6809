// Times in the browser's local time (relative ones get it as a tooltip, with the zone);
// reload every data-refresh seconds, but only once the server answers: after an outage or a
// restart the page stays, says when the server last answered, and keeps trying.
document.querySelectorAll("time[datetime]").forEach(function (t) {
  var d = new Date(t.getAttribute("datetime"));
  if (isNaN(d)) { return; }
  var text = d.toLocaleString(undefined, { timeZoneName: "short" });
  t.title = text;
  if (!t.classList.contains("rel")) { t.textContent = text; }
});
var every = Number(document.body.dataset.refresh || 0);
var answered = new Date();  // the server's last answer: this page
var since = null;
function check() {
  // a cheap probe first (not the page itself: that rendered it twice per reload)
  fetch("/healthz", { cache: "no-store", credentials: "same-origin" })
    .then(function (r) {
      if (r.ok) { location.reload(); return; }
      throw new Error("HTTP " + r.status);
    })
    .catch(function () {
      if (since === null) { since = new Date(); }
      var banner = document.getElementById("unreachable");
      if (!banner) {
        banner = document.createElement("div");
        banner.id = "unreachable";
        banner.className = "banner";
        document.body.insertBefore(banner, document.body.firstChild);
      }
      document.body.classList.add("stale");  // "... ago" stopped at that answer
      banner.textContent = "The study server cannot be reached (its last answer came at " +
        answered.toLocaleTimeString() + ", no answer since " + since.toLocaleTimeString() +
        "); this page shows what it said then, and tries again every " + every + " s.";
      setTimeout(check, every * 1000);
    });
}
if (every > 0) { setTimeout(check, every * 1000); }
