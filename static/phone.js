// The phone page: photo -> robot choice -> start -> follow -> stop.
"use strict";

(async () => {
  const $ = (id) => document.getElementById(id);
  let photo = null;        // Blob to upload
  let photoName = "goal";
  let runId = null;
  let closeStream = null;
  let maxSteps = 1000;
  let backendForm = null;

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

  function show(ev) {
    if (ev.run_id !== runId) return;
    $("progress-card").hidden = false;
    if (ev.status) $("run-badge").replaceChildren(imgnav.badge(ev.status));
    if (ev.step !== undefined) {
      $("run-step").textContent = `${ev.step + 1} (${ev.action})`;
      $("progress").value = ev.step + 1;
    }
    if (ev.mode !== undefined) $("run-mode").textContent = ev.mode || "-";
    if (ev.reason !== undefined) $("run-reason").textContent = ev.reason || "-";
    else if (ev.detail) $("run-reason").textContent = ev.detail;
    if (ev.reid_score !== undefined) {
      $("run-score").textContent = ev.reid_score === null ? "-" :
        `${imgnav.fmt(ev.reid_score, 1)} (threshold ${imgnav.fmt(ev.reid_tau, 1)})`;
    }
    if (ev.outcome) {
      const m = ev.metrics ? ` - success ${imgnav.fmt(ev.metrics.success)}, SPL ${imgnav.fmt(ev.metrics.spl)}, NE ${imgnav.fmt(ev.metrics.ne_m)} m` : "";
      $("run-outcome").replaceChildren(imgnav.badge(ev.outcome), ` ${ev.detail || ""}${m}`);
    }
    if (["finished", "stopped", "failed", "interrupted"].includes(ev.status)) {
      runId = null;
      if (closeStream) closeStream();
      $("stop").disabled = true;
      $("start").disabled = !photo;
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
      $("progress").max = (run.options && run.options.max_steps) || maxSteps;
      for (const id of ["run-step", "run-mode", "run-reason", "run-score", "run-outcome"]) $(id).textContent = "-";
      $("progress").value = 0;
      $("progress-card").hidden = false;
      $("run-badge").replaceChildren(imgnav.badge(run.status));
      $("stop").disabled = false;
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
    } catch (e) { showError(e.message); }
  });
})();
