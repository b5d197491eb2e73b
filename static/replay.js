// Replay of a finished run (phone and console pages): a timeline slider over the steps, the
// camera picture and the map as the agent knew it at each step, what it was doing and why,
// the re-ID score against tau, the goal candidates; jumps to the first detection, each
// rejected candidate and the stop. Opens on the last step (how the run ended). Mirrors a step in
// the shared 3D viewer only when this person moves the replay (opening a page changes nothing
// others are watching).
"use strict";

imgnav.Replay = class {
  constructor(root, options = {}) {
    this.root = root;
    this.options = options;  // { onStep(step) }: e.g. show the step in the 3D viewer
    this.runId = null;
    this.data = null;
    this.seq = 0;
  }

  async load(runId) {
    const { el } = imgnav;
    this.runId = runId;
    this.root.replaceChildren(el("p", { class: "hint", text: "Loading the replay..." }));
    const data = await imgnav.getJSON(`/api/runs/${runId}/replay`);
    if (runId !== this.runId) return;
    this.data = data;
    if (!data.steps.length) { this.root.replaceChildren(el("p", { class: "hint", text: "No steps to replay." })); return; }
    const n = data.steps.length;
    this.slider = el("input", { type: "range", id: "replay-slider", min: "1", max: String(n), value: "1", "aria-label": "step" });
    this.label = el("span", { id: "replay-step", class: "replay-step", text: `step 1 of ${n}` });
    const prev = el("button", { type: "button", id: "replay-prev", text: "‹", title: "previous step", "aria-label": "previous step" });
    const next = el("button", { type: "button", id: "replay-next", text: "›", title: "next step", "aria-label": "next step" });
    prev.addEventListener("click", () => this.go(this.current() - 1));
    next.addEventListener("click", () => this.go(this.current() + 1));
    this.slider.addEventListener("input", () => this.go(this.current(), true));
    const jumps = el("div", { class: "row jumps" });
    const m = data.marks || {};
    const jump = (id, text, step) => {
      const b = el("button", { type: "button", id, text, class: "small" });
      if (step === null || step === undefined) b.disabled = true;
      else b.addEventListener("click", () => this.go(step));
      jumps.append(b);
    };
    jump("jump-first-detection", "First detection", m.first_detection);
    (m.candidate_rejected || []).slice(0, 3).forEach((r, k) => jump(`jump-rejected-${k}`, `Candidate #${r.candidate} rejected`, r.step));
    jump("jump-stop", m.stop !== null && m.stop !== undefined ? "Stop" : "Last step", m.stop !== null && m.stop !== undefined ? m.stop : m.last);
    this.frame = el("img", { id: "replay-frame", alt: "what the robot saw", class: "replay-frame" });
    this.map = el("img", { id: "replay-map", alt: "the map as the robot knew it", class: "replay-map" });
    this.words = el("p", { id: "replay-words", class: "replay-words" });
    this.detail = el("p", { id: "replay-detail" });
    this.score = el("div", { class: "scorebar", id: "replay-score" });
    this.cands = el("div", { id: "replay-candidates" });
    this.root.replaceChildren(
      el("div", { class: "row replay-controls" }, prev, this.slider, next), this.label, jumps,
      el("div", { class: "replay-pictures" }, this.frame, this.map), imgnav.legend("map", "replay-legend"), this.words,
      el("details", { class: "tech" }, el("summary", { text: "Technical details" }), this.detail), this.score,
      el("h3", { text: "Goal candidates" }), this.cands,
    );
    await this.go(n - 1, false, false);  // the end of the run, without moving the shared 3D viewer
  }

  current() { return Number(this.slider.value) - 1; }

  // mirror: also show the step in the 3D viewer (options.onStep): only for this person's own moves
  async go(step, fromSlider = false, mirror = true) {
    if (!this.data) return;
    const n = this.data.steps.length;
    step = Math.max(0, Math.min(n - 1, step));
    if (!fromSlider) this.slider.value = String(step + 1);
    this.label.textContent = `step ${step + 1} of ${n}`;
    this.slider.setAttribute("aria-valuetext", this.label.textContent);
    const seq = ++this.seq;
    const s = await imgnav.getJSON(`/api/runs/${this.runId}/replay/${step}`);
    if (seq !== this.seq) return;  // the slider moved on meanwhile
    if (s.frame_url) this.frame.src = s.frame_url;
    this.map.src = s.map_url;
    this.words.textContent = s.words;
    this.detail.textContent = s.detail || "no technical note at this step";
    this.renderScore(s.reid_score, s.reid_tau);
    this.cands.replaceChildren(imgnav.candidatesTable(s.candidates, s.reid_tau));
    this.root.dataset.step = String(step);
    if (mirror && this.options.onStep) this.options.onStep(step);
  }

  renderScore(score, tau) {
    const { el } = imgnav;
    if (score === null || score === undefined) { this.score.replaceChildren(el("span", { class: "hint", text: "no match score at this step" })); return; }
    const top = Math.max(tau || 1, score) * 1.1;
    const bar = el("div", { class: "bar" }, el("div", { class: `fill ${tau && score >= tau ? "over" : ""}`, style: `width:${(100 * score / top).toFixed(1)}%` }));
    if (tau) bar.append(el("div", { class: "tau", style: `left:${(100 * tau / top).toFixed(1)}%`, title: `tau ${tau.toFixed(1)}` }));
    this.score.replaceChildren(bar, el("span", { class: "hint", text: `match score ${score.toFixed(1)}${tau ? ` (needs ${tau.toFixed(1)})` : ""}` }));
  }
};
