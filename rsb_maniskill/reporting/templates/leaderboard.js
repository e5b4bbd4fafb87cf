// The leaderboard's two controls: the metric shown (body's data-metric), and sorting by a column.
(function () {
  "use strict";
  const body = document.body;
  const table = document.getElementById("board");
  const tbody = table.tBodies[0];
  const heads = Array.from(table.tHead.rows[0].cells);
  const buttons = Array.from(document.querySelectorAll("button[data-metric]"));
  let sorted = null; // {index, dir}: the column the rows are sorted by

  // A cell's sort key: the shown metric's value, a number, or text; null when missing (sorts last).
  function key(row, index, kind) {
    const td = row.cells[index];
    const raw = kind === "metric" ? td.dataset[body.dataset.metric] : td.dataset.value;
    if (raw === undefined || raw === "") return null;
    return kind === "text" ? raw : parseFloat(raw);
  }

  function sort(index, dir) {
    const kind = heads[index].dataset.sort;
    const rows = Array.from(tbody.rows);
    rows.sort(function (a, b) {
      const x = key(a, index, kind), y = key(b, index, kind);
      if (x === null || y === null) return (x === null) - (y === null);
      if (kind === "text") return dir * x.localeCompare(y, undefined, {numeric: true, sensitivity: "base"});
      return dir * (x - y);
    });
    rows.forEach(function (r) { tbody.appendChild(r); });
    heads.forEach(function (h, i) {
      h.setAttribute("aria-sort", i === index ? (dir > 0 ? "ascending" : "descending") : "none");
    });
    sorted = {index: index, dir: dir};
  }

  heads.forEach(function (h, i) {
    if (!h.dataset.sort) return;
    h.tabIndex = 0;
    h.addEventListener("click", function () {
      const first = h.dataset.sort === "text" ? 1 : -1; // names A to Z, rates highest first
      sort(i, sorted && sorted.index === i ? -sorted.dir : first);
    });
    h.addEventListener("keydown", function (e) {
      if (e.key === "Enter" || e.key === " ") { e.preventDefault(); h.click(); }
    });
  });

  buttons.forEach(function (b) {
    b.addEventListener("click", function () {
      body.dataset.metric = b.dataset.metric;
      buttons.forEach(function (o) { o.setAttribute("aria-pressed", String(o === b)); });
      if (sorted && heads[sorted.index].dataset.sort === "metric") sort(sorted.index, sorted.dir);
    });
  });
})();
