"""Accessibility rules checked in a real page (browser tests): axe-core is not installed and the
tests run without a network, so the rules the console's pages must keep are written here as one
script evaluated in the page, from the computed styles and the DOM:

* text contrast: every visible text against its composited background, at least 4.5:1 (3:1 for
  large text: 24 px, or 18.66 px bold), WCAG 2's relative luminance; disabled controls are exempt;
* names: every input, select, textarea and button has an accessible name (aria-label,
  aria-labelledby, a <label>, a title, its text, or a placeholder for text boxes);
* focus order: no positive tabindex, and the keyboard's order (the DOM's, then) follows the
  visual order: each focusable element is below or to the right of the one before it.

``check_page(page)`` returns the problems as sentences (an empty list: none);
``check_page(page, every_badge=True)`` first adds to the page one badge of each state its style
sheets colour (``.badge.<state>``: run statuses, outcomes, candidate states), so that a state the
page is not showing now (a run that is active, failed, stopped) is checked too.
"""

from __future__ import annotations

from typing import Any

_RULES_JS = r"""
() => {
  const problems = [];
  const shown = (e) => {
    if (!(e instanceof Element)) return false;
    const r = e.getBoundingClientRect();
    const cs = getComputedStyle(e);
    return r.width > 0 && r.height > 0 && cs.visibility !== "hidden" && cs.display !== "none";
  };
  const describe = (e) => {
    const id = e.id ? `#${e.id}` : "";
    const cls = typeof e.className === "string" && e.className ? `.${e.className.trim().split(/\s+/).join(".")}` : "";
    return `<${e.tagName.toLowerCase()}${id}${cls}> "${(e.textContent || "").trim().slice(0, 40)}"`;
  };
  const rgba = (text) => {
    const m = text.match(/rgba?\(([^)]+)\)/);
    if (!m) return null;
    const p = m[1].split(/[\s,/]+/).filter(Boolean).map(Number);
    return [p[0], p[1], p[2], p.length > 3 ? p[3] : 1];
  };
  const over = (top, below) => {
    const a = top[3];
    return [0, 1, 2].map((k) => top[k] * a + below[k] * (1 - a)).concat([1]);
  };
  const luminance = (c) => {
    const f = (v) => { v /= 255; return v <= 0.03928 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; };
    return 0.2126 * f(c[0]) + 0.7152 * f(c[1]) + 0.0722 * f(c[2]);
  };
  // the background behind an element: its own and its ancestors' colours, composited on white
  const background = (e) => {
    const layers = [];
    for (let n = e; n; n = n.parentElement) {
      const c = rgba(getComputedStyle(n).backgroundColor);
      if (c && c[3] > 0) { layers.push(c); if (c[3] >= 1) break; }
    }
    let bg = [255, 255, 255, 1];
    for (const c of layers.reverse()) bg = over(c, bg);
    return bg;
  };
  const opacity = (e) => { let o = 1; for (let n = e; n; n = n.parentElement) o *= Number(getComputedStyle(n).opacity); return o; };

  // 1. contrast of every visible text
  for (const e of document.body.querySelectorAll("*")) {
    if (["SCRIPT", "STYLE", "OPTION", "IFRAME", "SVG", "IMG"].includes(e.tagName)) continue;
    const own = [...e.childNodes].some((n) => n.nodeType === Node.TEXT_NODE && n.textContent.trim());
    if (!own || !shown(e)) continue;
    if (e.closest("button:disabled, input:disabled, select:disabled, [aria-disabled=true]")) continue;
    const cs = getComputedStyle(e);
    const bg = background(e);
    const fg0 = rgba(cs.color);
    const fg = over([fg0[0], fg0[1], fg0[2], fg0[3] * opacity(e)], bg);
    const [l1, l2] = [luminance(fg), luminance(bg)].sort((a, b) => b - a);
    const ratio = (l1 + 0.05) / (l2 + 0.05);
    const size = parseFloat(cs.fontSize), bold = Number(cs.fontWeight) >= 700;
    const need = size >= 24 || (bold && size >= 18.66) ? 3 : 4.5;
    if (ratio < need) problems.push(`contrast ${ratio.toFixed(2)}:1 < ${need}:1: ${describe(e)} (${cs.color} on rgb(${bg.slice(0, 3).map(Math.round)}))`);
  }

  // 2. every control has an accessible name
  const named = (e) => {
    if ((e.getAttribute("aria-label") || "").trim()) return true;
    const by = e.getAttribute("aria-labelledby");
    if (by && by.split(/\s+/).some((id) => (document.getElementById(id)?.textContent || "").trim())) return true;
    if (e.labels && [...e.labels].some((l) => l.textContent.trim())) return true;
    if ((e.getAttribute("title") || "").trim()) return true;
    if (e.tagName === "BUTTON" && e.textContent.trim()) return true;
    if (e.tagName === "INPUT" && ["submit", "button", "reset"].includes(e.type) && e.value.trim()) return true;
    return false;
  };
  for (const e of document.querySelectorAll("input, select, textarea, button")) {
    if (e.type === "hidden" || getComputedStyle(e).display === "none" || e.closest("[hidden]")) continue;
    if (!named(e)) problems.push(`no accessible name: ${describe(e)}`);
  }

  // 3. focus order: no positive tabindex; the DOM's order follows the visual order
  for (const e of document.querySelectorAll("[tabindex]")) {
    if (e.tabIndex > 0) problems.push(`positive tabindex ${e.tabIndex}: ${describe(e)}`);
  }
  const inFixed = (e) => { for (let n = e; n; n = n.parentElement) if (getComputedStyle(n).position === "fixed") return true; return false; };
  const focusable = [...document.querySelectorAll("a[href], button, input, select, textarea, iframe, summary, [tabindex]")]
    .filter((e) => e.tabIndex >= 0 && !e.disabled && shown(e) && !inFixed(e));
  const box = (e) => { const r = e.getBoundingClientRect(); return { top: r.top + scrollY, left: r.left + scrollX, right: r.right + scrollX, bottom: r.bottom + scrollY }; };
  for (let k = 1; k < focusable.length; k++) {
    const a = box(focusable[k - 1]), b = box(focusable[k]);
    if (!(b.top >= a.top - 4 || b.left >= a.right - 4)) {  // below it, or to its right (a next column)
      problems.push(`focus goes up from ${describe(focusable[k - 1])} to ${describe(focusable[k])}`);
    }
  }
  return problems;
}
"""


# one badge of every state the page's style sheets colour, in a card at the end of the page
_ADD_BADGES_JS = r"""
() => {
  const states = new Set([""]);
  for (const sheet of document.styleSheets) {
    let rules;
    try { rules = sheet.cssRules; } catch (e) { continue; }
    for (const r of rules) for (const m of (r.selectorText || "").matchAll(/\.badge\.([\w-]+)/g)) states.add(m[1]);
  }
  const box = document.createElement("div");
  box.className = "card";
  box.id = "a11y-every-badge";
  for (const state of states) {
    const b = document.createElement("span");
    b.className = `badge ${state}`;
    b.textContent = state || "plain";
    box.append(b, " ");
  }
  document.body.append(box);
  return [...states].filter(Boolean);
}
"""


def check_page(page: Any, every_badge: bool = False) -> list[str]:
    """The page's accessibility problems (contrast, names, focus order), as sentences; with
    ``every_badge``, with one badge of each state the style sheets know added for the check."""
    if not every_badge:
        return list(page.evaluate(_RULES_JS))
    states = page.evaluate(_ADD_BADGES_JS)
    try:
        if "running" not in states:  # the style sheet was not read: the check would prove nothing
            return [f"no badge states found in the page's style sheets: {states}"]
        return list(page.evaluate(_RULES_JS))
    finally:
        page.evaluate("() => document.getElementById('a11y-every-badge').remove()")
