// The phone page: photo -> robot choice -> start -> follow (time, steps, area, distance,
// candidates, live picture and map) -> outcome in words -> replay.
"use strict";

(async () => {
  const $ = (id) => document.getElementById(id);
  const { el } = imgnav;
  let photo = null;        // Blob to upload
  let photoName = "goal";
  let runId = null;
  let closeStream = null;
  let backendForm = null;
  let startedAt = null;
  let clock = null;

  const showError = (msg) => { $("error").textContent = msg || ""; };

  function setPhoto(blob, name, fromGallery) {
    photo = blob;
    photoName = name || "goal";
    if (!fromGallery && backendForm) backendForm.clearGallery();
    const url = URL.createObjectURL(blob);
    const img = $("preview");
    img.hidden = false;
    img.onerror = () => {  // e.g. HEIC: the browser cannot show it, the server can read it
      img.hidden = true;
      $("photo-note").textContent = `${photoName}: no preview in this browser, but it will be uploaded.`;
    };
    img.src = url;
    $("photo-note").textContent = `${photoName} (${Math.round(blob.size / 1024)} kB)`;
    $("start").disabled = !!runId;
  }

  for (const id of ["camera-input", "file-input"]) {
    $(id).addEventListener("change", (ev) => {
      const f = ev.target.files && ev.target.files[0];
      if (f) setPhoto(f, f.name, false);
    });
  }

  let config;
  try {
    config = await imgnav.getJSON("/api/config");
  } catch (e) {
    showError(`Cannot reach the console: ${e.message}`);
    return;
  }
  const viewer = imgnav.viewerURL(config);
  if (viewer) { $("viewer-link").href = viewer; $("viewer-link").hidden = false; }
  if (config.token_required) {
    $("token-box").hidden = false;
    $("token").value = imgnav.token();
    $("token").addEventListener("change", () => localStorage.setItem("imgnav-token", $("token").value.trim()));
  }
  backendForm = new imgnav.BackendForm($("backend-form"), config, (blob, g) => setPhoto(blob, g.label, true));
  try { await backendForm.load(); } catch (e) { showError(e.message); }

  const replay = new imgnav.Replay($("replay"));

  $("live-legend-box").replaceChildren(imgnav.legend("map", "live-legend"));

  // One recorded step in the progress card: live (at most once a second), and once more at the
  // end with the run's last step, so that nothing stale is left beside the outcome.
  function showStep(s, final) {
    // what it does (the match has its own line): "turning to look at a possible match, turn left"
    const doing = [s.doing || imgnav.modeWords(s.mode), imgnav.actionWords(s.action_name)].filter(Boolean).join(", ");
    $("run-mode").textContent = final ? `Step ${s.step + 1}: ${doing}` : doing;
    if (s.frame_url) { $("live-frame").src = s.frame_url; $("live-frame").hidden = false; }
    $("live-map").src = s.map_url; $("live-map").hidden = false;
    $("live-legend-box").hidden = false;
    if (s.explored_m2 !== null && s.explored_m2 !== undefined) $("run-area").textContent = `${Math.round(s.explored_m2)} m²`;
    const best = imgnav.bestCandidate(s.candidates);
    if (final) {
      // at the end: the object as the robot placed it, and the best match it had of it
      $("run-target-label").textContent = "to object";
      $("run-target").textContent = best ? `${best.distance_m.toFixed(1)} m` : "-";
      $("run-score-label").textContent = "Best match";
      $("run-score").textContent = best ? `${imgnav.fmt(best.best_score, 1)} of ${imgnav.fmt(s.reid_tau, 1)} needed (#${best.id})`
        : "no candidate";
    } else {
      $("run-target-label").textContent = "to target";
      if (s.target && s.x_m !== undefined && s.x_m !== null) {
        $("run-target").textContent = `${Math.hypot(s.target[0] - s.x_m, s.target[1] - s.y_m).toFixed(1)} m`;
      }
      $("run-score-label").textContent = "Match";
      $("run-score").textContent = s.reid_score === null || s.reid_score === undefined ? "-" :
        `${imgnav.fmt(s.reid_score, 1)} of ${imgnav.fmt(s.reid_tau, 1)} needed`;
    }
    const live = (s.candidates || []).filter((c) => c.state !== "rejected");
    const rejected = (s.candidates || []).filter((c) => c.state === "rejected");
    let cands = live.length
      ? `${live.length} found: ` + live.map((c) => `#${c.id} ${c.state}, ${c.distance_m.toFixed(1)} m away`).join("; ")
      : (final ? "none left" : "none yet");
    if (final && rejected.length) cands += `; given up: ${rejected.map((c) => `#${c.id}${c.why ? ` (${c.why})` : ""}`).join(", ")}`;
    $("run-candidates").replaceChildren(cands);
    if (!final && live.some((c) => c.state === "confirmed")) $("run-phase").textContent = "Candidate found: checking it";
  }

  const peek = new imgnav.LivePeek((s, id) => { if (runId && id === runId) showStep(s, false); });

  function tick() {
    if (startedAt) $("run-time").textContent = imgnav.duration((Date.now() - startedAt) / 1000);
  }

  async function finish(id) {
    clearInterval(clock);
    const r = await imgnav.getJSON(`/api/runs/${id}`);
    // a run that ended before its first step has no step to show (asking would be a 404)
    const last = r.n_steps > 0 ? await imgnav.getJSON(`/api/runs/${id}/replay/latest`).catch(() => null) : null;
    $("run-outcome").replaceChildren(imgnav.summary(r));
    $("run-outcome").hidden = false;
    $("run-phase").hidden = true;  // the outcome above says how it ended
    $("run-step").textContent = String(r.n_steps);
    if (r.started_s && r.ended_s) $("run-time").textContent = imgnav.duration(r.ended_s - r.started_s);
    if (last) showStep(last, true);
    $("progress-card").scrollIntoView({ block: "start" });  // the outcome first
    $("replay-card").hidden = false;
    await replay.load(id);
  }

  function show(ev) {
    if (ev.run_id !== runId) return;
    if (ev.status) $("run-badge").replaceChildren(imgnav.badge(ev.status));
    if (ev.kind === "status" && ev.status === "running" && ev.detail) $("run-phase").textContent = "Preparing the robot and the agent...";
    if (ev.step !== undefined) {
      if (ev.step === 0) startedAt = startedAt || Date.now();
      $("run-step").textContent = String(ev.step + 1);
      const mode = imgnav.modeWords(ev.mode) || "moving";  // the step itself is on the "Doing" line
      $("run-phase").textContent = mode.charAt(0).toUpperCase() + mode.slice(1);
      peek.offer(runId, ev.step);
    }
    if (["finished", "stopped", "failed", "interrupted"].includes(ev.status)) {
      const id = runId;
      runId = null;
      if (closeStream) closeStream();
      $("stop").disabled = true;
      $("start").disabled = !photo;
      finish(id).catch((e) => showError(e.message));
    }
  }

  $("start").addEventListener("click", async () => {
    showError("");
    if (!photo) { showError("Take or choose a photo first."); return; }
    const form = new FormData();
    form.append("goal_image", photo, photoName);
    backendForm.fill(form);
    $("start").disabled = true;
    try {
      const run = await imgnav.postForm("/api/runs", form);
      runId = run.id;
      $("run-id").textContent = run.id;
      for (const id of ["run-step", "run-mode", "run-score", "run-area", "run-target"]) $(id).textContent = "-";
      $("run-outcome").replaceChildren();
      $("run-outcome").hidden = true;
      $("run-target-label").textContent = "to target";
      $("run-score-label").textContent = "Match";
      $("run-candidates").textContent = "none yet";
      $("run-phase").textContent = "Preparing the robot and the agent...";
      $("run-phase").hidden = false;
      $("live-frame").hidden = $("live-map").hidden = $("live-legend-box").hidden = true;
      $("replay-card").hidden = true;
      $("progress-card").hidden = false;
      $("run-badge").replaceChildren(imgnav.badge(run.status));
      $("stop").disabled = false;
      $("progress-card").scrollIntoView({ behavior: "smooth", block: "start" });
      startedAt = Date.now();
      clearInterval(clock);
      clock = setInterval(tick, 1000);
      closeStream = imgnav.follow(`/api/runs/${run.id}/events`, show);
    } catch (e) {
      showError(e.message);
      $("start").disabled = false;
    }
  });

  $("stop").addEventListener("click", async () => {
    if (!runId) return;
    try {
      await imgnav.postJSON(`/api/runs/${runId}/stop`);
      $("stop").disabled = true;
      $("run-phase").textContent = "Stopping after the current step...";
    } catch (e) { showError(e.message); }
  });
})();
