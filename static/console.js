// The desktop console: live viewer, new run, run list, run details and artifacts.
"use strict";

(async () => {
  const $ = (id) => document.getElementById(id);
  const { el, fmt, badge } = imgnav;
  let photo = null, photoName = "goal", selected = null, activeRun = null, backendForm = null;

  const showError = (msg) => { $("error").textContent = msg || ""; };
  const log = (line) => {
    const pre = $("log");
    pre.textContent += `${new Date().toLocaleTimeString()} ${line}\n`;
    pre.scrollTop = pre.scrollHeight;
  };

  const config = await imgnav.getJSON("/api/config");
  const viewer = imgnav.viewerURL(config);
  if (viewer) { $("viewer-frame").src = viewer; $("viewer-link").href = viewer; }
  else { $("viewer-link").hidden = true; }
  if (config.token_required) {
    $("token-box").hidden = false;
    $("token").value = imgnav.token();
    $("token").addEventListener("change", () => localStorage.setItem("imgnav-token", $("token").value.trim()));
  }

  function setPhoto(blob, name, fromGallery) {
    photo = blob; photoName = name;
    if (!fromGallery) backendForm.clearGallery();
    $("preview").hidden = false;
    $("preview").src = URL.createObjectURL(blob);
    $("photo-note").textContent = `${name} (${Math.round(blob.size / 1024)} kB)`;
    $("start").disabled = !!activeRun;
  }
  $("file-input").addEventListener("change", (ev) => {
    const f = ev.target.files && ev.target.files[0];
    if (f) setPhoto(f, f.name, false);
  });
  backendForm = new imgnav.BackendForm($("backend-form"), config, (blob, g) => setPhoto(blob, g.label, true));
  await backendForm.load();

  function setActive(runId) {
    activeRun = runId;
    $("active-run").replaceChildren(runId ? `run ${runId} active` : "idle");
    $("active-run").className = `badge ${runId ? "running" : ""}`;
    $("stop").disabled = !runId;
    $("start").disabled = !!runId || !photo;
  }

  async function refreshRuns() {
    const data = await imgnav.getJSON("/api/runs?limit=50");
    setActive(data.active_run);
    const body = $("runs");
    body.replaceChildren();
    for (const r of data.runs) {
      const tr = el("tr", { "data-run": r.id },
        el("td", { text: r.id }),
        el("td", { text: new Date(r.created_s * 1000).toLocaleString() }),
        el("td", {}, badge(r.status)),
        el("td", {}, badge(r.outcome || "")),
        el("td", { text: String(r.n_steps) }),
        el("td", { text: r.metrics ? fmt(r.metrics.spl) : "-" }));
      if (r.id === selected) tr.classList.add("selected");
      tr.addEventListener("click", () => showRun(r.id));
      body.append(tr);
    }
    if (!selected && data.runs.length) showRun(data.runs[0].id);
  }

  async function showRun(runId) {
    selected = runId;
    for (const tr of $("runs").querySelectorAll("tr")) tr.classList.toggle("selected", tr.dataset.run === runId);
    const r = await imgnav.getJSON(`/api/runs/${runId}`);
    $("details-card").hidden = false;
    $("details-id").textContent = r.id;
    const d = $("details");
    d.replaceChildren();
    const add = (k, v) => d.append(el("dt", { text: k }), el("dd", {}, v));
    add("Status", badge(r.status));
    add("Outcome", el("span", {}, badge(r.outcome || ""), ` ${r.outcome_detail || ""}`));
    add("Backend", `${r.backend} ${JSON.stringify(r.options)}`);
    add("Target", r.target ? JSON.stringify(r.target) : "unknown (not scored)");
    if (r.metrics) add("Metrics", Object.entries(r.metrics).map(([k, v]) => `${k} ${fmt(v)}`).join(", "));
    add("Steps", String(r.n_steps));
    const t = r.timings || {};
    add("Timings", ["upload_to_first_action_s", "open_s", "reset_s", "mean_step_ms", "artifacts_s", "total_s"]
      .filter((k) => t[k] !== undefined).map((k) => `${k} ${fmt(t[k])}`).join(", ") || "-");
    const a = $("artifacts");
    a.replaceChildren();
    const links = el("p", {});
    for (const [name, url] of Object.entries(r.artifacts || {})) links.append(el("a", { href: url, target: "_blank", text: name }), " ");
    a.append(links);
    for (const name of ["run.webp", "map.png", "goal.png"]) {
      if (r.artifacts && r.artifacts[name]) a.append(el("img", { src: `${r.artifacts[name]}?t=${r.ended_s || ""}`, alt: name, loading: "lazy" }));
    }
  }

  $("start").addEventListener("click", async () => {
    showError("");
    if (!photo) { showError("Choose a goal photo first."); return; }
    const form = new FormData();
    form.append("goal_image", photo, photoName);
    backendForm.fill(form);
    $("start").disabled = true;
    try {
      const run = await imgnav.postForm("/api/runs", form);
      log(`run ${run.id} started`);
      selected = run.id;
      setActive(run.id);
      await refreshRuns();
    } catch (e) { showError(e.message); $("start").disabled = false; }
  });
  $("stop").addEventListener("click", async () => {
    if (!activeRun) return;
    try { await imgnav.postJSON(`/api/runs/${activeRun}/stop`); log(`stop requested for ${activeRun}`); }
    catch (e) { showError(e.message); }
  });

  let refreshTimer = null;
  imgnav.follow("/api/events", (ev) => {
    if (ev.kind === "log") { log(ev.message); if (ev.ready) backendForm.load(); return; }
    if (ev.kind === "step") {  // keep the active run's row current without reloading the list
      const row = $("runs").querySelector(`tr[data-run="${ev.run_id}"]`);
      if (row) row.children[4].textContent = String(ev.step + 1);
      return;
    }
    if (ev.kind === "status") {
      log(`run ${ev.run_id}: ${ev.status}${ev.outcome ? ` - ${ev.outcome} (${ev.detail || ""})` : ""}`);
      clearTimeout(refreshTimer);
      refreshTimer = setTimeout(async () => { await refreshRuns(); if (selected === ev.run_id) showRun(ev.run_id); }, 150);
    }
  });
  await refreshRuns();
})().catch((e) => { document.getElementById("error").textContent = e.message; });
