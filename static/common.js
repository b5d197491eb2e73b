// Shared helpers of the phone and console pages (plain JS, no build step).
"use strict";

const imgnav = (() => {
  // The token: from ?token=... once, then remembered in this browser.
  const params = new URLSearchParams(window.location.search);
  if (params.get("token")) {
    localStorage.setItem("imgnav-token", params.get("token"));
  }
  const token = () => localStorage.getItem("imgnav-token") || "";

  function headers() {
    const h = {};
    if (token()) h["X-Imgnav-Token"] = token();
    return h;
  }

  async function describeError(resp) {
    let text = `${resp.status} ${resp.statusText}`;
    try {
      const body = await resp.json();
      const d = body.detail;
      if (d && d.message) text = `${d.message} (${resp.status} ${d.code})`;
      else if (Array.isArray(d)) text = d.map((e) => `${(e.loc || []).join(".")}: ${e.msg}`).join("; ");
      else if (typeof d === "string") text = d;
    } catch (_) { /* not JSON */ }
    return text;
  }

  async function getJSON(url) {
    const resp = await fetch(url, { headers: headers() });
    if (!resp.ok) throw new Error(await describeError(resp));
    return resp.json();
  }

  async function postForm(url, form) {
    const resp = await fetch(url, { method: "POST", body: form, headers: headers() });
    if (!resp.ok) throw new Error(await describeError(resp));
    return resp.json();
  }

  async function postJSON(url) {
    const resp = await fetch(url, { method: "POST", headers: headers() });
    if (!resp.ok) throw new Error(await describeError(resp));
    return resp.json();
  }

  function el(tag, attrs = {}, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k === "class") node.className = v;
      else if (k === "text") node.textContent = v;
      else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else node.setAttribute(k, v);
    }
    for (const c of children) node.append(c);
    return node;
  }

  function badge(text) {
    return el("span", { class: `badge ${text || ""}`, text: text || "-" });
  }

  function fmt(v, digits = 2) {
    if (v === null || v === undefined) return "-";
    if (typeof v === "number") return Number.isInteger(v) ? String(v) : v.toFixed(digits);
    if (typeof v === "boolean") return v ? "yes" : "no";
    return String(v);
  }

  // Follow a server-sent-event stream; returns a function that closes it. onConnection(true|false)
  // says whether the console is reachable (EventSource reconnects by itself).
  function follow(url, onEvent, onConnection) {
    const source = new EventSource(url);
    for (const kind of ["status", "step", "log"]) {
      source.addEventListener(kind, (ev) => onEvent(JSON.parse(ev.data)));
    }
    if (onConnection) {
      source.addEventListener("open", () => onConnection(true));
      source.addEventListener("error", () => onConnection(false));
    }
    return () => source.close();
  }

  // The agent's modes and actions in words (console/words.py says the same on the server).
  const MODE_WORDS = {
    look_around: "looking around", explore: "exploring", approach: "driving to the object",
    verify: "checking the object up close", rescan: "looking around again",
    stopped: "stopped at the object", exhausted: "gave up",
    last_resort: "going back to the best candidate left",
  };
  const ACTION_WORDS = { STOP: "stop", MOVE_FORWARD: "forward", TURN_LEFT: "turn left", TURN_RIGHT: "turn right" };
  const modeWords = (m) => (m ? MODE_WORDS[m] || m.replace(/_/g, " ") : "");
  const actionWords = (a) => (a ? ACTION_WORDS[a] || a.replace(/_/g, " ").toLowerCase() : "");

  function duration(seconds) {
    if (seconds === null || seconds === undefined || !isFinite(seconds)) return "-";
    if (seconds < 10) return `${Math.max(0, seconds).toFixed(1)} s`;  // as console/words.py says it
    const s = Math.round(seconds);
    if (s < 60) return `${s} s`;
    const m = Math.floor(s / 60);
    return m < 60 ? `${m} min ${s % 60} s` : `${Math.floor(m / 60)} h ${m % 60} min`;
  }

  // A run's outcome in words: the headline, then the sentence (which never repeats it), and the
  // technical account behind a disclosure (from the API's "summary").
  function summary(run) {
    const s = run.summary || { headline: run.status, sentence: "", tone: "neutral" };
    const box = el("div", { class: `summary ${s.tone}` }, el("strong", { class: "headline", text: `${s.headline}.` }), " ",
      el("span", { class: "sentence", text: s.sentence }));
    if (s.detail) box.append(technical(s.detail));
    return box;
  }

  // A technical line for people who want it, closed by default.
  function technical(text, label = "Technical details") {
    return el("details", { class: "tech" }, el("summary", { text: label }), el("p", { text }));
  }

  // Legends: the colours of the 3D view (console/viewer/scene.py) and of the 2D map pictures
  // (console/pictures.py); each colour means one thing.
  const LEGENDS = {
    scene: [
      ["robot", "#2864e6", "robot and camera"], ["trajectory", "#14963c", "path driven"],
      ["plan", "#fab400", "planned path"], ["frontier-target", "#ff00c8", "frontier target"],
      ["goal", "#e61e28", "goal points / goal target"], ["potential", "#ff8c00", "candidate (potential)"],
      ["confirmed", "#00b450", "candidate (confirmed)"], ["rejected", "#9a5abe", "candidate rejected"],
      ["walls", "#5a648c", "walls and furniture"], ["explored", "#c4d0e4", "floor seen"],
      ["frontier", "#00bedc", "edge of the explored area"], ["collision", "#8c3c14", "bumped into"],
      ["blacklist", "#808080", "given up (not searched again)"],
    ],
    map: [
      ["robot", "#145ae6", "robot"], ["trajectory", "#14823c", "path driven"], ["plan", "#fab400", "planned path"],
      ["target", "#ff00c8", "target"], ["goal", "#e61e28", "goal points"], ["candidate", "#ff8c00", "goal candidate"],
      ["explored", "#c4d0e4", "floor seen"], ["visited", "#b2deba", "floor driven over"],
      ["obstacle", "#464e6e", "walls and furniture"], ["frontier", "#00bedc", "edge of the explored area"],
      ["collision", "#8c3c14", "bumped into"], ["blacklist", "#808080", "given up (not searched again)"],
      ["unknown", "#30343c", "not seen yet"],
    ],
  };
  function legend(kind, id) {
    const box = el("p", { class: "legend", id: id || `legend-${kind}` });
    for (const [key, colour, text] of LEGENDS[kind]) {
      box.append(el("span", { "data-key": key }, el("i", { style: `background:${colour}` }), text));
    }
    return box;
  }

  // Goal candidates as a table: state, views, best score, distance.
  function candidatesTable(cands, tau) {
    if (!cands || !cands.length) return el("p", { class: "hint", text: "No goal candidate yet." });
    const body = el("tbody", {});
    for (const c of cands) {
      // a rejected candidate says why it was given up (hover, and after the badge)
      const state = c.why ? el("td", { title: c.why }, badge(c.state), el("small", { class: "why", text: ` ${c.why}` }))
        : el("td", {}, badge(c.state));
      body.append(el("tr", { class: `cand ${c.state}` },
        el("td", { text: `#${c.id}` }), state,
        el("td", { text: String(c.n_views) }),
        el("td", { text: `${fmt(c.best_score, 1)}${tau ? ` / ${fmt(tau, 1)}` : ""}` }),
        el("td", { text: `${fmt(c.distance_m, 1)} m` })));
    }
    return el("table", { class: "cands" },
      el("thead", {}, el("tr", {}, ...["", "state", "views", "best match", "distance"].map((h) => el("th", { text: h })))), body);
  }

  // Live details of the active run, at most once a second: camera, map, candidates, words.
  class LivePeek {
    constructor(onData) { this.onData = onData; this.busy = false; this.last = 0; this.pending = null; }
    offer(runId, step) {
      this.pending = { runId, step };
      const now = Date.now();
      if (this.busy || now - this.last < 1000) { clearTimeout(this.timer); this.timer = setTimeout(() => this.offer(runId, step), 1000); return; }
      this.busy = true; this.last = now;
      const p = this.pending;
      // the latest step whose pictures are stored (the step event can arrive just before they are)
      getJSON(`/api/runs/${p.runId}/replay/latest`).then((s) => this.onData(s, p.runId)).catch(() => {}).finally(() => { this.busy = false; });
    }
  }

  // The best goal candidate not rejected (highest score), or null.
  function bestCandidate(cands) {
    const live = (cands || []).filter((c) => c.state !== "rejected");
    return live.length ? live.reduce((a, b) => (b.best_score > a.best_score ? b : a)) : null;
  }

  function viewerURL(config) {
    if (!config.viewer) return null;
    return `${window.location.protocol}//${window.location.hostname}:${config.viewer.port}/`;
  }

  // The backend choice: a <select> of backends and, for the simulator, home, start and gallery.
  // Calls onGalleryPick(blob, item) when a gallery image is chosen as the goal photo.
  class BackendForm {
    constructor(root, config, onGalleryPick) {
      this.root = root;
      this.config = config;
      this.onGalleryPick = onGalleryPick;
      this.galleryItem = "";
      this.sim = null;
      this.backendSel = el("select", { id: "backend", name: "backend" });
      for (const b of config.backends) {
        const o = el("option", { value: b.name, text: b.label + (b.available ? "" : ` (${b.why})`) });
        if (!b.available && b.name !== "sim") o.disabled = true;
        this.backendSel.append(o);
      }
      if (config.default_backend) this.backendSel.value = config.default_backend;
      this.simBox = el("div", { id: "sim-options" });
      root.append(el("label", { for: "backend", text: "Robot" }), this.backendSel, this.simBox);
      this.backendSel.addEventListener("change", () => this.render());
    }

    async load() {
      if (this.config.backends.some((b) => b.name === "sim")) {
        this.sim = await getJSON("/api/backends/sim");
      }
      this.render();
    }

    render() {
      this.simBox.replaceChildren();
      if (this.backendSel.value !== "sim" || !this.sim) return;
      if (!this.sim.available) {
        this.simBox.append(el("p", { class: "hint", id: "sim-preparing", text: `Simulator: ${this.sim.why}` }));
        return;
      }
      const homes = this.sim.homes || [];
      this.homeSel = el("select", { id: "sim-home", name: "home" });
      for (const h of homes) this.homeSel.append(el("option", { value: h.id, text: h.label }));
      this.startSel = el("select", { id: "sim-start", name: "start" });
      this.gallery = el("div", { class: "gallery", id: "gallery" });
      this.simBox.append(
        el("label", { for: "sim-home", text: "Home" }), this.homeSel,
        el("label", { for: "sim-start", text: "Start" }), this.startSel,
        el("label", { text: "Gallery: tap an object to use its picture as the goal photo" }), this.gallery,
      );
      this.homeSel.addEventListener("change", () => this.renderHome());
      this.episodeSel = null;
      if ((this.sim.episodes || []).length) {
        this.episodeSel = el("select", { id: "sim-episode", name: "episode" });
        this.episodeSel.append(el("option", { value: "", text: "none: choose home, start and photo" }));
        for (const e of this.sim.episodes) this.episodeSel.append(el("option", { value: e.id, text: e.label }));
        this.episodeSel.addEventListener("change", async () => {
          const e = this.sim.episodes.find((x) => x.id === this.episodeSel.value);
          this.homeSel.disabled = this.startSel.disabled = !!e;
          if (e) {
            this.clearGallery();
            this.onGalleryPick(await (await fetch(e.goal_image_url)).blob(), { label: `${e.id} goal image`, item: "" });
          }
        });
        this.simBox.append(el("label", { for: "sim-episode", text: "Or an episode (fixes home, start and target)" }), this.episodeSel);
      }
      this.renderHome();
    }

    home() {
      return (this.sim.homes || []).find((h) => h.id === this.homeSel.value);
    }

    renderHome() {
      const home = this.home();
      this.startSel.replaceChildren();
      this.gallery.replaceChildren();
      if (!home) return;
      for (const s of home.starts) this.startSel.append(el("option", { value: s.id, text: s.label }));
      for (const g of home.gallery) {
        // a button for the keyboard too (Enter or Space picks it)
        const fig = el("figure", { "data-item": g.item, title: g.label, role: "button", tabindex: "0", "aria-label": `use ${g.label} as the goal photo` },
          el("img", { src: g.url, alt: "", loading: "lazy" }), el("figcaption", { text: g.label }));
        fig.addEventListener("keydown", (ev) => { if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); fig.click(); } });
        fig.addEventListener("click", async () => {
          for (const f of this.gallery.querySelectorAll("figure")) f.classList.remove("selected");
          fig.classList.add("selected");
          const blob = await (await fetch(g.url)).blob();
          this.galleryItem = g.item;
          // a start that makes a real search (not the one next to the object)
          if (g.default_start) this.startSel.value = g.default_start;
          this.onGalleryPick(blob, g);
        });
        this.gallery.append(fig);
      }
    }

    clearGallery() {
      this.galleryItem = "";
      if (this.gallery) for (const f of this.gallery.querySelectorAll("figure")) f.classList.remove("selected");
    }

    // Preset the form from a stored run's options ("run again with this photo").
    preset(options) {
      if (!options) return;
      if (this.episodeSel && options.episode) { this.episodeSel.value = options.episode; return; }
      if (this.homeSel && options.home) { this.homeSel.value = options.home; this.renderHome(); }
      if (this.startSel && options.start && [...this.startSel.options].some((o) => o.value === options.start)) {
        this.startSel.value = options.start;
      }
    }

    fill(form) {
      form.append("backend", this.backendSel.value);
      if (this.backendSel.value === "sim" && this.episodeSel && this.episodeSel.value) {
        form.append("episode", this.episodeSel.value);
      } else if (this.backendSel.value === "sim" && this.homeSel) {
        form.append("home", this.homeSel.value);
        form.append("start", this.startSel.value);
        if (this.galleryItem) form.append("gallery_item", this.galleryItem);
      }
    }
  }

  return {
    token, getJSON, postForm, postJSON, el, badge, fmt, follow, viewerURL, BackendForm, describeError,
    modeWords, actionWords, duration, summary, technical, legend, candidatesTable, LivePeek, bestCandidate,
  };
})();
