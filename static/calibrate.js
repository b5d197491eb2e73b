// Calibrate a deployment's tau from the operator's own photos: objects with several photos
// each -> every pair scored with the deployment's matcher -> PR and F curves, max-F tau -> save.
"use strict";

(async () => {
  const $ = (id) => document.getElementById(id);
  const { el, fmt } = imgnav;
  const objects = [];  // { name, files: File[] }
  let job = null;

  const showError = (msg) => { $("error").textContent = msg || ""; };

  const config = await imgnav.getJSON("/api/config");
  if (config.token_required) {
    $("token-box").hidden = false;
    $("token").value = imgnav.token();
    $("token").addEventListener("change", () => localStorage.setItem("imgnav-token", $("token").value.trim()));
  }

  async function showInForce() {
    const st = await imgnav.getJSON("/api/calibration");
    const d = st[$("deployment").value];
    $("in-force").textContent = `In force now: tau ${fmt(d.tau, 1)} (${d.matcher}, ${d.score}) from ${d.source}.`;
  }
  $("deployment").addEventListener("change", showInForce);
  await showInForce();

  function pairsNote() {
    const n = objects.reduce((a, o) => a + o.files.length, 0);
    const same = objects.reduce((a, o) => a + (o.files.length * (o.files.length - 1)) / 2, 0);
    const ready = objects.filter((o) => o.files.length).length >= 2 && objects.every((o) => !o.files.length || o.files.length >= 2);
    $("pairs-note").textContent = n ? `${n} photos: ${same} same-object pairs, ${n * (n - 1) / 2 - same} different-object pairs.` : "";
    $("run").disabled = !ready;
  }

  function addObject(name) {
    const k = objects.length;
    const obj = { name: name || `object ${k + 1}`, files: [] };
    objects.push(obj);
    const input = el("input", { type: "file", accept: "image/*", multiple: "multiple", id: `object-files-${k}` });
    const camera = el("input", { type: "file", accept: "image/*", capture: "environment", id: `object-camera-${k}` });
    const thumbs = el("div", { class: "thumbs" });
    const nameBox = el("input", { type: "text", value: obj.name, id: `object-name-${k}`, "aria-label": "object name" });
    nameBox.addEventListener("change", () => { obj.name = nameBox.value.trim() || obj.name; });
    const add = (files) => {
      for (const f of files) {
        obj.files.push(f);
        thumbs.append(el("img", { src: URL.createObjectURL(f), alt: f.name, title: f.name }));
      }
      pairsNote();
    };
    input.addEventListener("change", () => add(input.files));
    camera.addEventListener("change", () => add(camera.files));
    $("objects").append(el("div", { class: "object" },
      el("label", { for: `object-name-${k}`, text: `Object ${k + 1}` }), nameBox,
      el("div", { class: "row file-buttons" },
        el("label", { class: "button", for: `object-camera-${k}`, text: "Take a photo" }),
        el("label", { class: "button", for: `object-files-${k}`, text: "Choose photos" })),
      input, camera, thumbs));
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

  async function pollJob(id) {
    for (;;) {
      const j = await imgnav.getJSON(`/api/calibration/jobs/${id}`);
      $("progress").value = j.progress;
      $("status").textContent = `${j.state}: ${j.message || ""}`;
      if (j.state === "done" || j.state === "failed") return j;
      await new Promise((r) => setTimeout(r, 500));
    }
  }

  $("run").addEventListener("click", async () => {
    showError("");
    const form = new FormData();
    for (const o of objects) for (const f of o.files) { form.append("photos", f, f.name); form.append("objects", o.name); }
    $("run").disabled = true;
    $("progress").hidden = false;
    try {
      job = await imgnav.postForm(`/api/calibration/${$("deployment").value}`, form);
      const done = await pollJob(job.id);
      if (done.state === "failed") throw new Error(done.error);
      const r = done.result, p = r.proposal, c = r.curves[p.score];
      $("result-card").hidden = false;
      $("proposal").textContent =
        `Proposed tau ${fmt(p.tau, 1)} (${p.matcher}, ${p.score} score): F ${fmt(p.max_f)}, precision ${fmt(p.precision)}, ` +
        `recall ${fmt(p.recall)}. It accepts ${p.same_pairs_accepted} of ${r.same_pairs} same-object pairs and ` +
        `${p.different_pairs_accepted} of ${r.different_pairs} different-object pairs (${r.photos} photos of ` +
        `${Object.keys(r.objects).length} objects, ${done.seconds.toFixed(1)} s).`;
      $("curves").replaceChildren(curvesSvg(c));
      $("saved").textContent = "";
      $("result-card").scrollIntoView({ behavior: "smooth", block: "start" });
    } catch (e) { showError(e.message); }
    finally { $("run").disabled = false; }
  });

  $("save").addEventListener("click", async () => {
    if (!job) return;
    try {
      const res = await imgnav.postJSON(`/api/calibration/jobs/${job.id}/save`);
      $("saved").textContent = `Saved: ${$("deployment").value} now uses tau ${fmt(res.in_force.tau, 1)} (${res.in_force.source}).`;
      await showInForce();
    } catch (e) { showError(e.message); }
  });
})().catch((e) => { document.getElementById("error").textContent = e.message; });
