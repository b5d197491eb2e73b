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
  let lastPose = null;

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

  const peek = new imgnav.LivePeek((s) => {
    if (!runId) return;
    $("run-mode").textContent = s.words.replace(/^Step \d+: /, "");
    if (s.frame_url) { $("live-frame").src = s.frame_url; $("live-frame").hidden = false; }
    $("live-map").src = s.map_url; $("live-map").hidden = false;
    if (s.explored_m2 !== null && s.explored_m2 !== undefined) $("run-area").textContent = `${Math.round(s.explored_m2)} m²`;
    if (s.target && lastPose) {
      const d = Math.hypot(s.target[0] - lastPose[0], s.target[1] - lastPose[1]);
      $("run-target").textContent = `${d.toFixed(1)} m`;
    }
    const live = (s.candidates || []).filter((c) => c.state !== "rejected");
    $("run-candidates").replaceChildren(live.length
      ? `${live.length} found: ` + live.map((c) => `#${c.id} ${c.state}, ${c.distance_m.toFixed(1)} m away`).join("; ")
      : "none yet");
    if (live.some((c) => c.state === "confirmed")) $("run-phase").textContent = "Candidate found: checking it";
  });

  function tick() {
    if (startedAt) $("run-time").textContent = imgnav.duration((Date.now() - startedAt) / 1000);
  }

  async function finish(id) {
    clearInterval(clock);
    const r = await imgnav.getJSON(`/api/runs/${id}`);
    $("run-outcome").replaceChildren(imgnav.summary(r));
    $("run-phase").textContent = r.summary ? r.summary.headline : r.status;
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
      $("run-phase").textContent = `${imgnav.modeWords(ev.mode) || "moving"} (${imgnav.actionWords(ev.action_name)})`;
      lastPose = [ev.x_m, ev.y_m, ev.yaw_rad];
      if (ev.reid_score !== undefined) {
        $("run-score").textContent = ev.reid_score === null ? "-" :
          `${imgnav.fmt(ev.reid_score, 1)} of ${imgnav.fmt(ev.reid_tau, 1)} needed`;
      }
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
      for (const id of ["run-step", "run-mode", "run-score", "run-outcome", "run-area", "run-target"]) $(id).textContent = "-";
      $("run-candidates").textContent = "none yet";
      $("run-phase").textContent = "Preparing the robot and the agent...";
      $("live-frame").hidden = $("live-map").hidden = true;
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
