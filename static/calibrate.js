// Calibrate a deployment's tau from the operator's own photos: objects with several photos
// each -> every pair scored with the deployment's matcher -> PR and F curves, max-F tau -> save
// (what changes is shown first; a save can be undone). A job runs on the console, so a reloaded
// page finds it again (the job list, and the id this tab started in sessionStorage).
"use strict";

(async () => {
  const $ = (id) => document.getElementById(id);
  const { el, fmt } = imgnav;
  const JOB_KEY = "imgnav-calibration-job";
  const objects = [];  // { name, files: File[] }
  let job = null;  // the job whose result is shown (its view)
  let running = false;
  let status = null;  // GET /api/calibration: each deployment's tau in force, limits

  const showError = (msg) => { $("error").textContent = msg || ""; };
  const robotName = (d) => ($("deployment").querySelector(`option[value="${d}"]`) || { textContent: d }).textContent;

  const config = await imgnav.getJSON("/api/config");
  if (config.token_required) {
    $("token-box").hidden = false;
    $("token").value = imgnav.token();
    $("token").addEventListener("change", () => localStorage.setItem("imgnav-token", $("token").value.trim()));
  }
  // The robot this console drives: a console with only the simulator calibrates the simulator.
  const backends = (config.backends || []).map((b) => b.name);
  $("deployment").value = backends.includes("stretch") ? "stretch" : "sim";

  async function showInForce() {
    status = await imgnav.getJSON("/api/calibration");
    const dep = $("deployment").value, d = status[dep];
    $("in-force").textContent = `In force now: tau ${fmt(d.tau, 1)} (${d.matcher}, ${d.score}) from ${d.source}.`;
    $("undo-box").hidden = !d.undo;
    $("undo-note").textContent = d.undo ? `Undo puts back tau ${fmt(d.undo.tau, 1)} from ${d.undo.source}.` : "";
  }
  $("deployment").addEventListener("change", async () => { await showInForce(); pairsNote(); });
  await showInForce();

  // Why "Score all pairs" cannot be pressed now ("" when it can), from the console's own limits.
  function runReason() {
    const lim = status.limits;
    if (running) return "Scoring is under way; the result appears below.";
    const used = objects.filter((o) => o.files.length);
    const n = used.reduce((a, o) => a + o.files.length, 0);
    const same = used.reduce((a, o) => a + (o.files.length * (o.files.length - 1)) / 2, 0);
    const different = (n * (n - 1)) / 2 - same;
    if (used.length < lim.min_objects) {
      return `Add photos of at least ${lim.min_objects} different objects (${used.length} so far).`;
    }
    const few = used.filter((o) => o.files.length < lim.min_views_per_object);
    if (few.length) {
      return `Each object needs at least ${lim.min_views_per_object} photos: ` +
        few.map((o) => `${o.name} has ${o.files.length}`).join(", ") + ".";
    }
    if (n > lim.max_photos) return `At most ${lim.max_photos} photos at once (${n} now): remove some.`;
    if (same < lim.min_same_pairs || different < lim.min_different_pairs) {
      return `${same} same-object and ${different} different-object pairs: a threshold needs at least ` +
        `${lim.min_same_pairs} and ${lim.min_different_pairs}. Add an object or more photos of each.`;
    }
    return "";
  }

  function pairsNote() {
    const n = objects.reduce((a, o) => a + o.files.length, 0);
    const same = objects.reduce((a, o) => a + (o.files.length * (o.files.length - 1)) / 2, 0);
    $("pairs-note").textContent = n ? `${n} photos: ${same} same-object pairs, ${n * (n - 1) / 2 - same} different-object pairs.` : "";
    const why = runReason();
    $("run").disabled = Boolean(why);
    $("run-why").textContent = why;
  }

  const fileKey = (f) => `${f.name}|${f.size}|${f.lastModified}`;

  function addObject(name) {
    const k = objects.length;
    const obj = { name: name || `object ${k + 1}`, files: [] };
    objects.push(obj);
    const input = el("input", { type: "file", accept: "image/*", multiple: "multiple", id: `object-files-${k}` });
    const camera = el("input", { type: "file", accept: "image/*", capture: "environment", id: `object-camera-${k}` });
    const thumbs = el("div", { class: "thumbs", id: `object-thumbs-${k}` });
    const nameBox = el("input", { type: "text", value: obj.name, id: `object-name-${k}`, "aria-label": "object name" });
    nameBox.addEventListener("change", () => { obj.name = nameBox.value.trim() || obj.name; pairsNote(); });
    const add = (files) => {
      showError("");
      const known = new Set(objects.flatMap((o) => o.files.map(fileKey)));
      const repeated = [];
      for (const f of files) {
        if (known.has(fileKey(f))) { repeated.push(f.name); continue; }  // the same file twice: no new view
        known.add(fileKey(f));
        obj.files.push(f);
        const url = URL.createObjectURL(f);
        const figure = el("figure", { class: "thumb" },
          el("img", { src: url, alt: f.name, title: f.name }));
        figure.append(el("button", {
          type: "button", class: "remove", text: "×", title: `Remove ${f.name}`,
          "aria-label": `Remove ${f.name} from ${obj.name}`,
          onclick: () => {
            obj.files.splice(obj.files.indexOf(f), 1);
            URL.revokeObjectURL(url);
            figure.remove();
            pairsNote();
          },
        }));
        thumbs.append(figure);
      }
      if (repeated.length) showError(`Already added (the same file is no new view): ${repeated.join(", ")}`);
      pairsNote();
    };
    // the inputs are emptied after use, so that a removed photo can be chosen again
    input.addEventListener("change", () => { add(input.files); input.value = ""; });
    camera.addEventListener("change", () => { add(camera.files); camera.value = ""; });
    $("objects").append(el("div", { class: "object" },
      el("label", { for: `object-name-${k}`, text: `Object ${k + 1}` }), nameBox,
      el("div", { class: "row file-buttons" },
        el("label", { class: "button", for: `object-camera-${k}`, text: "Take a photo" }),
        el("label", { class: "button", for: `object-files-${k}`, text: "Choose photos" })),
      input, camera, thumbs));
    pairsNote();
  }
  $("add-object").addEventListener("click", () => addObject());
  addObject(); addObject();

  function curvesSvg(c) {
    // PR curve (left) and F against tau (right), plain SVG.
    const W = 300, H = 200, P = 30;
    const path = (xs, ys, sx, sy) => xs.map((x, i) => `${i ? "L" : "M"}${(P + sx(x)).toFixed(1)},${(H - P - sy(ys[i])).toFixed(1)}`).join("");
    const unit = (v) => v * (W - 2 * P);
    const unitY = (v) => v * (H - 2 * P);
    const tMax = Math.max(...c.threshold, 1);
    const svg = `<svg class="curves" id="curves-svg" viewBox="0 0 ${2 * W} ${H}" xmlns="http://www.w3.org/2000/svg" font-size="10">
      <g><rect x="${P}" y="${P}" width="${W - 2 * P}" height="${H - 2 * P}" fill="none" stroke="#ccc"/>
        <path d="${path(c.recall_curve, c.precision_curve, unit, unitY)}" fill="none" stroke="#1f77b4" stroke-width="2"/>
        <circle cx="${P + unit(c.recall)}" cy="${H - P - unitY(c.precision)}" r="4" fill="#d62728"/>
        <text x="${W / 2}" y="${H - 8}" text-anchor="middle">recall</text><text x="8" y="${H / 2}" transform="rotate(-90 8 ${H / 2})" text-anchor="middle">precision</text>
        <text x="${W / 2}" y="16" text-anchor="middle">precision-recall</text></g>
      <g transform="translate(${W},0)"><rect x="${P}" y="${P}" width="${W - 2 * P}" height="${H - 2 * P}" fill="none" stroke="#ccc"/>
        <path d="${path(c.threshold, c.f_curve, (t) => unit(t / tMax), unitY)}" fill="none" stroke="#2ca02c" stroke-width="2"/>
        <line x1="${P + unit(c.tau / tMax)}" x2="${P + unit(c.tau / tMax)}" y1="${P}" y2="${H - P}" stroke="#d62728" stroke-dasharray="4 3"/>
        <text x="${W / 2}" y="${H - 8}" text-anchor="middle">tau (0 - ${tMax.toFixed(0)})</text><text x="${W / 2}" y="16" text-anchor="middle">F-measure against tau</text></g>
    </svg>`;
    const box = el("div", {});
    box.innerHTML = svg;  // built from numbers only
    return box;
  }

  function pairsTable(r) {
    const score = r.proposal.score;
    const rows = [...r.pair_scores].sort((a, b) => b[score] - a[score]);
    return [
      el("tr", {}, ...["photo", "photo", "pair", `score (${score})`, "at this tau"].map((t) => el("th", { text: t }))),
      ...rows.map((p) => el("tr", {},
        el("td", { text: p.a }), el("td", { text: p.b }), el("td", { text: p.same ? "same object" : "different objects" }),
        el("td", { text: fmt(p[score], 1) }), el("td", { text: p.accepted ? "accepted" : "refused" }))),
    ];
  }

  function showResult(done) {
    job = done;
    const r = done.result, p = r.proposal, c = r.curves[p.score], checks = r.checks;
    $("result-card").hidden = false;
    $("proposal").textContent =
      `Proposed tau ${fmt(p.tau, 1)} (${p.matcher}, ${p.score} score): F ${fmt(p.max_f)}, precision ${fmt(p.precision)}, ` +
      `recall ${fmt(p.recall)}. It accepts ${p.same_pairs_accepted} of ${r.same_pairs} same-object pairs and ` +
      `${p.different_pairs_accepted} of ${r.different_pairs} different-object pairs (${r.photos} photos of ` +
      `${Object.keys(r.objects).length} objects, ${fmt(done.seconds, 1)} s).`;
    $("problems").textContent = checks.problems.map((x) => x.message).join("\n");
    $("curves").replaceChildren(curvesSvg(c));
    $("pairs-table").replaceChildren(...pairsTable(r));
    const now = status[done.deployment];
    $("change").textContent =
      `Saving changes the tau of ${robotName(done.deployment)} from ${fmt(now.tau, 1)} (${now.source}) to ${fmt(p.tau, 1)}, ` +
      `from ${r.same_pairs} same-object pairs (${p.same_pairs_accepted} accepted) and ${r.different_pairs} ` +
      `different-object pairs (${p.different_pairs_accepted} accepted). It can be undone.`;
    $("saved").textContent = "";
    setSave(saveReason());
  }

  // Why "Use this tau" cannot be pressed ("" when it can).
  function saveReason() {
    if (!job) return "No result to save yet.";
    if (!job.result.checks.savable) return "This tau cannot be saved: it would make the robot worse (the reason is above).";
    const saved = status[job.deployment].saved;
    if (saved && String(saved.source || "").endsWith(job.id)) return "This tau is in force now.";
    return "";
  }

  function setSave(why) {
    $("save").disabled = Boolean(why);
    $("save-why").textContent = why;
  }

  // the job's state in words: "Extracting keypoints of 9 photos", "Matching pair 3 of 36", "Done: ..."
  function statusWords(j) {
    const verb = { extracting: "Extracting", matching: "Matching", queued: "Waiting to start", failed: "Failed" }[j.state];
    if (j.state === "done") return "Done: every pair scored.";
    return verb ? `${verb}${j.message ? " " + j.message : ""}` : j.message || j.state;
  }

  async function follow(id) {
    running = true;
    pairsNote();
    $("progress").hidden = false;
    try {
      for (;;) {
        const j = await imgnav.getJSON(`/api/calibration/jobs/${id}`);
        $("progress").value = j.progress;
        $("status").textContent = statusWords(j);
        if (j.state === "failed") throw new Error(j.error);
        if (j.state === "done") {
          $("deployment").value = j.deployment;
          await showInForce();
          showResult(j);
          return;
        }
        await new Promise((r) => setTimeout(r, 500));
      }
    } finally {
      running = false;
      pairsNote();
    }
  }

  $("run").addEventListener("click", async () => {
    showError("");
    const form = new FormData();
    for (const o of objects) for (const f of o.files) { form.append("photos", f, f.name); form.append("objects", o.name); }
    running = true;
    pairsNote();
    try {
      const started = await imgnav.postForm(`/api/calibration/${$("deployment").value}`, form);
      sessionStorage.setItem(JOB_KEY, started.id);
      await follow(started.id);
      $("result-card").scrollIntoView({ behavior: "smooth", block: "start" });
    } catch (e) { showError(e.message); }
    finally { running = false; pairsNote(); }
  });

  $("save").addEventListener("click", async () => {
    if (!job) return;
    showError("");
    try {
      const res = await imgnav.postJSON(`/api/calibration/jobs/${job.id}/save`);
      await showInForce();
      setSave(saveReason());
      $("saved").textContent = `Saved: ${job.deployment} now uses tau ${fmt(res.in_force.tau, 1)} (${res.in_force.source}); ` +
        `it used ${fmt(res.previous.tau, 1)} (${res.previous.source}).`;
    } catch (e) { showError(e.message); }
  });

  $("undo").addEventListener("click", async () => {
    showError("");
    const dep = $("deployment").value;
    try {
      const res = await imgnav.postJSON(`/api/calibration/${dep}/undo`);
      await showInForce();
      if (job) setSave(saveReason());
      $("undo-note").textContent = `Undone: ${dep} uses tau ${fmt(res.in_force.tau, 1)} again (${res.in_force.source}).`;
    } catch (e) { showError(e.message); }
  });

  // A reloaded page: follow the running job, or show the one this tab started.
  const { jobs } = await imgnav.getJSON("/api/calibration/jobs");
  const mine = sessionStorage.getItem(JOB_KEY);
  const resume = jobs.find((j) => j.state !== "done" && j.state !== "failed") || jobs.find((j) => j.id === mine);
  if (resume) {
    $("deployment").value = resume.deployment;
    await showInForce();
    try { await follow(resume.id); } catch (e) { showError(e.message); }
  }
})().catch((e) => { document.getElementById("error").textContent = e.message; });
