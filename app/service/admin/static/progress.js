// Live progress of the journeys on this page: poll while any of them is queued or running.
"use strict";
(function () {
  const ACTIVE = new Set(["queued", "running"]);
  const rows = new Map([...document.querySelectorAll("tr[data-id]")].map(r => [r.dataset.id, r]));

  async function poll() {
    const active = [...rows.values()].filter(r => ACTIVE.has(r.dataset.status)).map(r => r.dataset.id);
    if (!active.length) return;
    try {
      const answer = await fetch(`/admin/journeys/progress.json?ids=${active.join(",")}`,
                                 {credentials: "same-origin"});
      if (answer.ok && answer.headers.get("content-type").includes("json")) {
        for (const [id, p] of Object.entries(await answer.json())) update(rows.get(id), p);
      }
    } finally {
      setTimeout(poll, 2000);
    }
  }

  function update(row, p) {
    row.dataset.status = p.status;
    const status = row.querySelector(".status");
    status.textContent = p.status;
    status.className = `status status-${p.status}`;
    row.querySelector(".stage").textContent = p.stage || "";
    row.querySelector(".fill").style.width = `${(p.progress * 100).toFixed(1)}%`;
    row.querySelector(".bar").title = `${Math.round(p.progress * 100)} %`;
    row.querySelector(".error-cell").textContent = p.error || p.message || "";
    row.querySelector(".n-signs").textContent = p.n_signs == null ? "" : p.n_signs;
  }
  setTimeout(poll, 2000);
})();
