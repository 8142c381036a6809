// Times in the browser's local time (relative ones get it as a tooltip); reload every
// data-refresh seconds.
document.querySelectorAll("time[datetime]").forEach(function (t) {
  var d = new Date(t.getAttribute("datetime"));
  if (isNaN(d)) { return; }
  t.title = d.toLocaleString();
  if (!t.classList.contains("rel")) { t.textContent = d.toLocaleString(); }
});
var every = Number(document.body.dataset.refresh || 0);
if (every > 0) { setTimeout(function () { location.reload(); }, every * 1000); }
