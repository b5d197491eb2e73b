// The desktop console: live viewer, new run, live candidates, run list (filters), a run's
// outcome in words, its replay (here and in the 3D viewer), numbers and artifacts.
"use strict";

(async () => {
  const $ = (id) => document.getElementById(id);
  const { el, fmt, badge } = imgnav;
  let photo = null, photoName = "goal", selected = null, activeRun = null, backendForm = null, reachable = true;

  const showError = (msg) => { $("error").textContent = msg || ""; };
  const log = (line) => {
    const pre = $("log");
    pre.textContent += `${new Date().toLocaleTimeString()} ${line}\n`;
    pre.scrollTop = pre.scrollHeight;
  };

  const config = await imgnav.getJSON("/api/config");
  const viewer = imgnav.viewerURL(config);
  $("legend-box").replaceChildren(imgnav.legend("scene", "legend"));
  $("live-legend-box").replaceChildren(imgnav.legend("map", "live-legend"));
  if (viewer) { $("viewer-frame").src = viewer; $("viewer-link").href = viewer; }
  else { $("viewer-link").hidden = true; $("legend").hidden = true; }
  if (config.token_required) {
    $("token-box").hidden = false;
    $("token").value = imgnav.token();
    $("token").addEventListener("change", () => localStorage.setItem("imgnav-token", $("token").value.trim()));
  }
  for (const b of config.backends) $("filter-backend").append(el("option", { value: b.name, text: b.label }));

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
  const fillHomes = () => {
    const sel = $("filter-home");
    const known = new Set([...sel.options].map((o) => o.value));
    for (const h of (backendForm.sim && backendForm.sim.homes) || []) {
      if (!known.has(h.id)) sel.append(el("option", { value: h.id, text: h.id }));
    }
  };
  fillHomes();

  // The memory of the selected simulator home, or of the robot's home when the robot is chosen
  // (GET /api/memory/{home}): its map (each known object numbered with its request), the known
  // objects (each request that ended with a candidate not rejected) with the goal photo they were
  // asked with and "Find it again" (a run from memory with that photo: POST /api/runs with
  // goal_from_run), why it was last dropped (the robot's, when its map frame was lost), and
  // forgetting it.
  let memoryHome = null, memoryInUse = false;
  const memoryHomes = await imgnav.getJSON("/api/memory").then((m) => m.backends || {}).catch(() => ({}));
  const homeChosen = () => {
    const backend = document.getElementById("backend");
    if (!backend) return null;
    if (backend.value !== "sim") return (memoryHomes[backend.value] || [])[0] || null;  // the robot's one home
    const sel = document.getElementById("sim-home");
    return sel && !sel.disabled ? sel.value : null;
  };
  const droppedWords = (d) => d
    ? ` Dropped ${new Date(d.at_s * 1000).toLocaleString()}${d.run_id ? ` (run ${d.run_id})` : ""}: ${d.reason}.`
    : "";
  let memorySeq = 0;  // refreshes overlap (a run's word, then its end): only the latest may write
  async function refreshMemory() {
    const seq = ++memorySeq;
    const home = homeChosen();
    memoryHome = home;
    $("memory-card").hidden = !home;
    if (!home) return;
    $("memory-home").textContent = home;
    let m;
    try { m = await imgnav.getJSON(`/api/memory/${encodeURIComponent(home)}`); }
    catch (e) { memoryError(e.message); return; }
    if (memoryHome !== home || seq !== memorySeq) return;  // another home chosen, or a later refresh meanwhile
    memoryError("");
    const requests = m.goals.length;
    $("memory-words").textContent = (requests
      ? `${requests} ${requests === 1 ? "request" : "requests"} in this home; ${m.keyframes} remembered ${m.keyframes === 1 ? "view" : "views"} `
        + `(${fmt((m.keyframe_bytes + m.map_bytes) / 1e6, 1)}\u00a0MB).${m.in_use ? " A run is adding to it now." : ""}`
      : "Nothing yet: the next run here starts from nothing, and later runs start from what it saw.")
      + droppedWords(m.dropped);
    $("memory-map").hidden = !requests;
    if (requests) $("memory-map").src = `${m.map_url}?t=${Date.now()}`;
    memoryInUse = m.in_use;
    const list = $("memory-objects");
    list.replaceChildren();
    for (const o of m.objects) {
      const more = o.candidates > 1 ? ` (and ${o.candidates - 1} more ${o.candidates === 2 ? "place" : "places"})` : "";
      const words = `request ${o.request}: ${o.state} object at (${fmt(o.xy_m[0], 1)}, ${fmt(o.xy_m[1], 1)}) m, `
        + `best score ${fmt(o.best_score, 1)}${more}`;
      const thumb = o.goal_url
        ? el("img", { class: "memory-thumb", src: o.goal_url, alt: `the goal photo of request ${o.request}` })
        : el("span", { class: "memory-thumb none", text: "no photo" });
      const again = el("button", {
        type: "button", class: "memory-again", "data-run": o.goal_url ? o.run_id : "",  // no photo: nothing to ask with
        "aria-label": `Find it again: request ${o.request}`,
        title: "a new run in this home, from memory, with this request's goal photo (from the start chosen above; the robot: from where it stands)",
        text: "Find it again",
      });
      again.disabled = !again.dataset.run || !!activeRun || m.in_use;
      again.addEventListener("click", () => findAgain(home, o));
      list.append(el("li", { "data-request": String(o.request) }, thumb, el("span", { text: words }), again));
    }
    if (!list.children.length) list.append(el("li", { class: "hint", text: "no object found yet" }));
    $("memory-forget").disabled = !requests || m.in_use;
  }
  const memoryError = (msg) => { $("memory-error").textContent = msg || ""; };
  async function findAgain(home, o) {
    memoryError("");
    for (const b of document.querySelectorAll("#memory-objects .memory-again")) b.disabled = true;  // one start at a time
    const form = new FormData();
    backendForm.fill(form);  // the home and the start chosen above
    form.delete("gallery_item");  // the photo is the request's own
    if (form.get("backend") === "sim") form.set("home", home);  // the robot's home is where it stands
    form.append("goal_from_run", o.run_id);
    await startRun(form, `request ${o.request} of ${home} asked again, from memory`, memoryError);
    setFindAgain();
  }
  const setFindAgain = () => {
    for (const b of document.querySelectorAll("#memory-objects .memory-again")) {
      b.disabled = !b.dataset.run || !!activeRun || memoryInUse;
    }
  };
  $("memory-forget").addEventListener("click", async () => {
    const home = memoryHome;
    if (!home) return;
    const headers = imgnav.token() ? { "X-Imgnav-Token": imgnav.token() } : {};
    const resp = await fetch(`/api/memory/${encodeURIComponent(home)}`, { method: "DELETE", headers });
    if (!resp.ok) { $("memory-error").textContent = await imgnav.describeError(resp); return; }
    log(`the memory of ${home} is forgotten`);
    await refreshMemory();
  });
  $("backend-form").addEventListener("change", () => refreshMemory().catch((e) => log(e.message)));
  await refreshMemory();

  function setBadge() {
    const b = $("active-run");
    if (!reachable) { b.replaceChildren("console unreachable"); b.className = "badge failed"; return; }
    b.replaceChildren(activeRun ? `run ${activeRun} active` : "idle");
    b.className = `badge ${activeRun ? "running" : ""}`;
  }

  function setActive(runId) {
    activeRun = runId;
    setBadge();
    $("stop").disabled = !runId;
    $("start").disabled = !!runId || !photo;
    setFindAgain();
    // the live card stays after the run ends, with its last state, until the next run starts
    if (runId && $("live-id").textContent !== runId) {
      $("live-card").hidden = false; $("live-id").textContent = runId; $("live-state").textContent = "";
      $("live-outcome").hidden = true;
    }
  }

  let runsSeq = 0;  // refreshes overlap (a filter changed, a run's status): only the latest may write
  async function refreshRuns() {
    const seq = ++runsSeq;
    const q = new URLSearchParams({ limit: "50" });
    for (const [k, id] of [["outcome", "filter-outcome"], ["home", "filter-home"], ["backend", "filter-backend"]]) {
      if ($(id).value) q.set(k, $(id).value);
    }
    const data = await imgnav.getJSON(`/api/runs?${q}`);
    if (seq !== runsSeq) return;
    setActive(data.active_run);
    const body = $("runs");
    body.replaceChildren();
    for (const r of data.runs) {
      const s = r.summary || {};
      const when = new Date(r.created_s * 1000);
      const tr = el("tr", { "data-run": r.id, title: `run ${r.id}: ${s.sentence || ""}` },
        el("td", { text: when.toLocaleDateString() === new Date().toLocaleDateString() ? when.toLocaleTimeString() : when.toLocaleString() }),
        el("td", {}, el("span", { class: `badge ${s.tone || ""}`, text: s.headline || r.status })),
        el("td", { text: String(r.n_steps) }),
        el("td", { text: r.metrics ? fmt(r.metrics.spl) : "-" }));
      if (r.id === selected) tr.classList.add("selected");
      tr.addEventListener("click", () => showRun(r.id));
      body.append(tr);
    }
    if (!selected && data.runs.length) showRun(data.runs[0].id);
  }
  for (const id of ["filter-outcome", "filter-home", "filter-backend"]) $(id).addEventListener("change", () => refreshRuns());

  const replay = new imgnav.Replay($("replay"), {
    onStep: (step) => {
      if (!$("replay-3d").checked || activeRun || !selected || !config.viewer) return;
      imgnav.postJSON(`/api/runs/${selected}/replay/${step}/show`).catch(() => {});
    },
  });

  function optionsWords(r) {
    const o = r.options || {};
    if (r.backend === "stretch") return `Hello Robot Stretch at ${o.host || "?"}, at most ${o.max_steps} steps`;
    if (r.backend !== "sim") return `${r.backend}, at most ${o.max_steps} steps`;
    if (o.episode) return `simulator episode ${o.episode}, at most ${o.max_steps} steps`;
    const start = o.start === "custom" && o.start_pose_world ? `(${o.start_pose_world.map((v) => v.toFixed(2)).join(", ")})` : o.start;
    return `simulator ${o.home || ""}, start ${start || "?"}, at most ${o.max_steps} steps`;
  }
  function targetWords(r) {
    const t = r.target;
    if (!t) return "unknown: the run is not scored";
    const what = `${t.category || "object"} #${t.instance_id}${t.room ? ` in the ${t.room}` : ""}`;
    return `${what} (known from ${t.identified_by || "?"})`;
  }

  let showSeq = 0;  // a run clicked while another's details load: only the latest may write
  async function showRun(runId) {
    const seq = ++showSeq;
    selected = runId;
    for (const tr of $("runs").querySelectorAll("tr")) tr.classList.toggle("selected", tr.dataset.run === runId);
    const r = await imgnav.getJSON(`/api/runs/${runId}`);
    if (seq !== showSeq) return;
    $("details-card").hidden = false;
    $("details-id").textContent = r.id;
    $("details-summary").replaceChildren(imgnav.summary(r));
    const d = $("details");
    d.replaceChildren();
    const add = (k, v) => d.append(el("dt", { text: k }), el("dd", {}, v));
    add("Robot", optionsWords(r));
    add("Looking for", targetWords(r));
    add("Started", new Date((r.started_s || r.created_s) * 1000).toLocaleString());
    // the outcome's technical account is in the summary's disclosure (imgnav.summary)
    const numbers = $("numbers");
    numbers.replaceChildren();
    const row = (k, v) => numbers.append(el("tr", {}, el("th", { text: k }), el("td", { text: v })));
    const m = r.metrics || {};
    if (r.metrics) {
      row("success", fmt(m.success)); row("SPL", fmt(m.spl, 3)); row("distance to goal (NE)", `${fmt(m.ne_m)} m`);
      if (m.path_length_m !== undefined) row("path driven", `${fmt(m.path_length_m, 1)} m`);
      if (m.shortest_path_m !== undefined) row("shortest path", `${fmt(m.shortest_path_m, 1)} m`);
    }
    row("steps", String(r.n_steps));
    for (const [k, v] of r.timings_words || []) row(k, v);
    const a = $("artifacts");
    a.replaceChildren();
    const links = el("p", {});
    for (const [name, url] of Object.entries(r.artifacts || {})) links.append(el("a", { href: url, target: "_blank", text: name }), " ");
    a.append(links);
    $("run-again").disabled = !(r.artifacts && Object.keys(r.artifacts).some((n) => n.startsWith("goal_upload")));
    $("run-again").onclick = async () => {
      const name = Object.keys(r.artifacts).find((n) => n.startsWith("goal_upload"));
      const blob = await (await fetch(r.artifacts[name])).blob();
      backendForm.preset(r.options);
      setPhoto(blob, `photo of run ${r.id}`, false);
      log(`photo of run ${r.id} ready: press Start`);
    };
    if (["finished", "stopped", "failed", "interrupted"].includes(r.status)) {
      await replay.load(r.id);
    } else {
      $("replay").replaceChildren(el("p", { class: "hint", text: "The replay is ready when the run has ended; follow it live in the viewer." }));
    }
  }

  $("start").addEventListener("click", async () => {
    showError("");
    if (!photo) { showError("Choose a goal photo first."); return; }
    const form = new FormData();
    form.append("goal_image", photo, photoName);
    backendForm.fill(form);
    if (homeChosen() && !$("memory-use").checked) form.append("memory", "off");
    await startRun(form, "", showError);
  });
  async function startRun(form, what, showErr) {
    $("start").disabled = true;
    try {
      const run = await imgnav.postForm("/api/runs", form);
      log(`run ${run.id} started${what ? `: ${what}` : ""}`);
      selected = run.id;
      setActive(run.id);
      $("live-words").textContent = "Preparing the robot and the agent...";
      await refreshRuns();
    } catch (e) { showErr(e.message); $("start").disabled = !!activeRun || !photo; }
  }
  $("stop").addEventListener("click", async () => {
    if (!activeRun) return;
    try { await imgnav.postJSON(`/api/runs/${activeRun}/stop`); log(`stop requested for ${activeRun}`); }
    catch (e) { showError(e.message); }
  });

  function showLive(s) {
    $("live-words").textContent = s.words;
    if (s.frame_url) $("live-frame").src = s.frame_url;
    $("live-map").src = s.map_url;
    $("candidates").replaceChildren(imgnav.candidatesTable(s.candidates, s.reid_tau));
  }
  let liveEnded = null;  // the run whose end the live card shows: late live answers are dropped
  const peek = new imgnav.LivePeek((s, id) => {
    if (!activeRun || id !== activeRun || id === liveEnded) return;
    showLive(s);
  });

  // The end of the run in the live card: its last recorded step and its outcome.
  async function showLiveEnd(runId) {
    liveEnded = runId;
    const r = await imgnav.getJSON(`/api/runs/${runId}`);
    // a run that ended before its first step has no step to show (asking would be a 404)
    const last = r.n_steps > 0 ? await imgnav.getJSON(`/api/runs/${runId}/replay/latest`).catch(() => null) : null;
    if ($("live-id").textContent !== runId) return;
    if (last) showLive(last);
    $("live-state").textContent = ` (ended: ${r.summary ? r.summary.headline : r.status})`;
    $("live-outcome").replaceChildren(imgnav.summary(r));
    $("live-outcome").hidden = false;
  }

  let refreshTimer = null;
  imgnav.follow("/api/events", (ev) => {
    if (ev.kind === "log") {
      log(ev.message);
      if (ev.ready) backendForm.load().then(fillHomes).then(refreshMemory);
      else if (ev.run_id) refreshMemory().catch(() => {});  // a run's word (its home's memory dropped)
      return;
    }
    if (ev.kind === "step") {  // keep the active run's row current without reloading the list
      const row = $("runs").querySelector(`tr[data-run="${ev.run_id}"]`);
      if (row) row.children[2].textContent = String(ev.step + 1);
      // the selected run's summary, while it runs, counts its steps too
      const running = ev.run_id === selected && $("details-summary").querySelector(".summary.active .sentence");
      if (running) running.textContent = `${ev.step + 1} ${ev.step === 0 ? "step" : "steps"} so far.`;
      if (ev.run_id === activeRun) peek.offer(ev.run_id, ev.step);
      return;
    }
    if (ev.kind === "status") {
      if (["finished", "stopped", "failed", "interrupted"].includes(ev.status) && $("live-id").textContent === ev.run_id) {
        showLiveEnd(ev.run_id).catch((e) => log(`run ${ev.run_id}: ${e.message}`));
      }
      log(`run ${ev.run_id}: ${ev.status}${ev.detail ? ` (${ev.detail})` : ""}`);
      if (["running", "finished", "stopped", "failed", "interrupted"].includes(ev.status)) refreshMemory().catch(() => {});
      clearTimeout(refreshTimer);
      refreshTimer = setTimeout(async () => { await refreshRuns(); if (selected === ev.run_id) showRun(ev.run_id); }, 150);
    }
  }, (ok) => {
    const was = reachable;
    reachable = ok;
    setBadge();
    if (ok && !was) refreshRuns();
  });
  await refreshRuns();
})().catch((e) => {
  document.getElementById("error").textContent = e.message;
  const b = document.getElementById("active-run");
  b.textContent = "console unreachable"; b.className = "badge failed";
});
