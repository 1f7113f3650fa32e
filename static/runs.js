// The runs kept on disk, in the page: the result of the run (its running figures while it
// goes, then its summary, warnings and plots), the runs list, a past run's results, and
// two runs compared (their settings' differences and their plots overlaid), a past run's
// 3D replay and ROS 2 bag. REST: /api/metrics (the run that is there), /api/runs,
// /api/runs/{id}, /api/runs/{id}/files/{name}, /api/runs/{id}/bag, /api/runs/compare,
// /api/runs/compare/plot. It lives in #runs-panel of index.html.
(() => {
  "use strict";
  const root = document.getElementById("runs-panel");
  if (!root) return;

  // --- small helpers ------------------------------------------------------------------
  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "class") node.className = v;
      else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else if (v !== null && v !== undefined) node.setAttribute(k, v);
    }
    for (const c of children.flat()) {
      if (c !== null && c !== undefined) node.append(c instanceof Node ? c : String(c));
    }
    return node;
  }
  async function getJSON(path, opts) {
    const res = await fetch(path, opts);
    let data = null;
    try { data = await res.json(); } catch (e) { /* not JSON */ }
    if (!res.ok) throw new Error((data && data.detail) || res.statusText);
    return data;
  }
  const num = (v, digits = 3) => (v === null || v === undefined ? "–" : Number(v).toFixed(digits));
  const mm = (v) => (v === null || v === undefined ? "–" : `${(1e3 * v).toFixed(2)} mm`);
  const pct = (v) => (v === null || v === undefined ? "–" : `${v >= 0 ? "+" : ""}${(100 * v).toFixed(1)} %`);
  const fileUrl = (id, name) => `/api/runs/${encodeURIComponent(id)}/files/${encodeURIComponent(name)}`;
  const plotsOf = (run) => (run.files || []).filter((f) => f.endsWith(".png"));
  const REPLAY = "replay.html";  // a run's 3D replay, kept in its folder
  const bagUrl = (id) => `/api/runs/${encodeURIComponent(id)}/bag`;
  const overlayUrl = (a, b, figure) => "/api/runs/compare/plot?" +
    new URLSearchParams({ a, b, figure }).toString();

  // --- the layout ---------------------------------------------------------------------
  const toggle = el("button", { type: "button", id: "runs-toggle",
                                title: "the run's result, the runs kept on disk, compare two" },
                    "Results & runs");
  const headline = el("span", { id: "runs-headline", class: "muted" });  // one line, always
  const body = el("div", { id: "runs-body" });
  const result = el("section", { id: "run-result" }, el("p", { class: "muted" },
                    "No run yet: start one; its result shows here."));
  const listBox = el("section", { id: "runs-list" });
  const compareBox = el("section", { id: "run-compare" });
  body.append(result, compareBox, listBox);
  root.append(el("div", { id: "runs-bar" }, toggle, headline), body);
  toggle.onclick = () => root.classList.toggle("open");

  // --- a run's summary ----------------------------------------------------------------
  function summary(metrics, title) {
    const box = el("div", { class: "run-summary" });
    if (title) box.append(el("h3", {}, title));
    if (!metrics || !metrics.satellites) {
      box.append(el("p", { class: "muted" }, "no metrics yet"));
      return box;
    }
    box.append(el("p", {}, `${metrics.scenario} · ${metrics.mode} · status ${metrics.status}` +
      ` · ${num(metrics.duration_s, 2)} s simulated · seed ${metrics.seed}`));
    const rows = metrics.satellites.map((s) => el("tr", {},
      el("td", {}, `${s.id} ${s.name}`), el("td", {}, mm(s.position_error_max_m)),
      el("td", {}, mm(s.position_error_rms_m)), el("td", {}, `${num(s.delta_v_mps, 4)} m/s`)));
    box.append(el("table", { class: "run-table" },
      el("tr", {}, el("th", {}, "satellite"), el("th", {}, "tracking error max"),
         el("th", {}, "rms"), el("th", {}, "Δv")), rows));
    const c = metrics.collision;
    if (c) {
      const iv = c.restitution_interval_95;
      box.append(el("p", { class: "result-restitution" },
        `restitution ${num(c.restitution)}` +
        (iv ? ` (95 % interval ${num(iv[0])} – ${num(iv[1])})` : "") +
        ` · ideal run ${num(c.restitution_ideal)} · error ${pct(c.restitution_error)}` +
        ` · peak force ${num(c.peak_force_N, 1)} N · contact at ${num(c.contact_start_s, 3)} s`));
      if (typeof c.rendering_error_m === "number" && c.contact_depth_m) {
        box.append(el("p", { class: "result-rendering" },
          `the mockups rendered the contact to ${num(1e6 * c.rendering_error_m, 1)} µm rms ` +
          `of overlap against the satellites' ${num(1e6 * c.contact_depth_m, 0)} µm ` +
          `contact depth (${num(100 * c.rendering_error_m / c.contact_depth_m, 1)} %)`));
      }
      if (c.true_impulse_ratio) {
        box.append(el("p", {}, "true impulse × ideal: " + Object.entries(c.true_impulse_ratio)
          .map(([k, v]) => `${k} ${num(v, 2)}`).join(", ")));
      }
    }
    const cap = metrics.capture;
    if (cap) box.append(el("p", {}, `capture: ${cap.captured ? "captured" : "not captured"}` +
      (cap.residual_rate_radps !== undefined ? ` · residual rate ${num(cap.residual_rate_radps, 4)} rad/s` : "")));
    const ok = metrics.success;
    if (ok) {
      const crit = Object.entries(ok).filter(([k, v]) => k !== "passed" && v && typeof v === "object");
      box.append(el("p", { class: ok.passed ? "pass" : "fail" },
        `success criteria: ${ok.passed ? "met" : "NOT met"}` + (crit.length ? " (" +
          crit.map(([k, v]) => `${k} ${v.passed ? "✓" : "✗"}`).join(", ") + ")" : "")));
    }
    const warnings = [...(metrics.warnings || []), ...((c && c.warnings) || [])];
    if (warnings.length) {
      box.append(el("ul", { class: "run-warnings" }, warnings.map((w) => el("li", {}, w))));
    }
    return box;
  }

  function plots(run) {
    const names = plotsOf(run);
    if (!names.length) {
      return el("p", { class: "muted" }, typeof run.plots === "string" && run.plots.startsWith("failed")
        ? `plots: ${run.plots}` : "plots: being drawn…");
    }
    return el("div", { class: "run-plots" }, names.map((n) =>
      el("a", { href: fileUrl(run.id, n), target: "_blank", title: n },
         el("img", { class: "run-plot", src: `${fileUrl(run.id, n)}?v=${run.ended_at || ""}`,
                     alt: n, loading: "lazy" }))));
  }

  function showRun(run, heading) {
    result.replaceChildren(
      el("h2", {}, heading || `Run ${run.id}`),
      el("p", { class: "muted" }, `${run.status}${run.reason ? ": " + run.reason : ""} · started ` +
        `${run.started_at}` + (run.ended_at ? ` · ended ${run.ended_at}` : "")),
      summary(run.metrics),
      plots(run),
      el("p", {}, (run.files || []).includes(REPLAY)
        ? el("a", { href: fileUrl(run.id, REPLAY), target: "_blank", class: "run-replay" },
             "open its 3D replay") : el("span", { class: "muted" }, "no 3D replay kept"),
        " · ", el("a", { href: bagUrl(run.id), download: `${run.id}-bag.zip`, class: "run-bag",
                         title: "built on demand from its telemetry (MCAP; Foxglove, PlotJuggler, ros2 bag play)" },
                  "ROS 2 bag")),
      el("p", {}, "files: ", (run.files || []).map((f) =>
        el("a", { href: fileUrl(run.id, f), download: f, class: "run-file" }, f))));
    result.dataset.runId = run.id;
  }

  // --- the run that is there: running figures, then its stored result ---------------------
  let followed = null;  // the id of the run recording or last recorded, shown in #run-result
  let pinned = false;   // a past run opened by hand: no following until the next run
  let lastList = null;
  let lastNewest = null;  // the newest run at the last look
  let metricsAt = 0;  // when the running figures were last asked for

  // one look at a time (every second): a slow server gets no queue of them, which would
  // hold the browser's connections to it while a Start from the page waits for one
  let looking = false;
  async function follow() {
    if (looking) return;
    looking = true;
    try { await look(); } finally { looking = false; }
  }

  async function look() {
    let list;
    try { list = await getJSON("/api/runs"); } catch (e) { return; }
    lastList = list;
    renderList(list);
    const recording = list.recording;
    const newest = list.runs.length ? list.runs[0].id : null;  // (ids sort by start time)
    if (recording && recording !== followed) { followed = recording; pinned = false; }
    else if (!recording && newest && newest !== lastNewest) {
      followed = newest; pinned = false;  // a new last run, even one that began and ended
    }                                     // between two looks
    lastNewest = newest;
    if (pinned || !followed) return;
    if (recording === followed) {  // running: the figures so far (every 3 s: they are
      if (Date.now() - metricsAt < 3000) return;  // computed from the whole ring)
      metricsAt = Date.now();
      try {
        const m = await getJSON("/api/metrics");
        result.replaceChildren(el("h2", {}, `Run ${followed} (running)`),
                               summary(m, "running figures"));
        result.dataset.runId = followed;
        headline.textContent = headlineText(followed, m);
      } catch (e) { /* not started yet */ }
      return;
    }
    const rec = list.runs.find((r) => r.id === followed);
    if (!rec) return;
    if (result.dataset.runId === followed && result.dataset.shown === String(rec.plots)) return;
    const run = await getJSON(`/api/runs/${encodeURIComponent(followed)}`);
    showRun(run, `Result of run ${run.id}`);
    result.dataset.shown = String(rec.plots);
    headline.textContent = headlineText(run.id, run.metrics, run.status);
  }

  // the line beside the button: the run's result at a glance (the panel opens on a click;
  // opening it by itself would move the 3D view under the user's hand)
  function headlineText(id, m, status) {
    if (!m || !m.satellites) return `run ${id}: ${status || "starting"}`;
    const c = m.collision;
    const warnings = (m.warnings || []).length + ((c && c.warnings) || []).length;
    return `run ${id}: ${status || m.status}` +
      ` · tracking error max ${m.satellites.map((s) => mm(s.position_error_max_m)).join(", ")}` +
      (c ? ` · restitution ${num(c.restitution)} (ideal ${num(c.restitution_ideal)}, ` +
           `error ${pct(c.restitution_error)})` : "") +
      (m.success ? ` · success ${m.success.passed ? "met" : "NOT met"}` : "") +
      (warnings ? ` · ${warnings} warning${warnings > 1 ? "s" : ""}` : "");
  }

  // --- the runs list ------------------------------------------------------------------
  const chosen = new Set();
  function renderList(list) {
    const key = JSON.stringify([list.runs.map((r) => [r.id, r.status, String(r.plots), r.replay]),
                                [...chosen]]);
    if (listBox.dataset.key === key) return;
    listBox.dataset.key = key;
    const rows = list.runs.map((r) => {
      const h = r.headline || {};
      const box = el("input", { type: "checkbox", class: "run-choose", "data-run-id": r.id,
                                title: "choose two to compare" });
      box.checked = chosen.has(r.id);
      box.onchange = () => { if (box.checked) chosen.add(r.id); else chosen.delete(r.id);
                             compareButton.disabled = chosen.size !== 2; };
      return el("tr", { "data-run-id": r.id },
        el("td", {}, box),
        el("td", {}, el("a", { href: "#", class: "run-open", onclick: (ev) => { ev.preventDefault(); open(r.id); } }, r.id)),
        el("td", {}, r.mode), el("td", {}, r.seed), el("td", {}, num(r.duration_s, 2)),
        el("td", {}, r.status),
        el("td", {}, num(h.restitution)), el("td", {}, num(h.restitution_ideal)),
        el("td", {}, pct(h.restitution_error)),
        el("td", {}, h.success === null || h.success === undefined ? "–" : (h.success ? "met" : "not met")),
        el("td", {}, r.replay ? el("a", { href: fileUrl(r.id, REPLAY), target: "_blank",
                                          class: "run-replay", title: "its 3D replay, in a new tab" }, "3D")
                              : "–"));
    });
    const compareButton = el("button", { type: "button", id: "compare-button", onclick: compare },
                             "Compare the two chosen");
    compareButton.disabled = chosen.size !== 2;
    listBox.replaceChildren(
      el("h2", {}, "Runs kept on disk"),
      el("p", { class: "muted", id: "runs-retention" }, list.retention),
      compareButton,
      el("table", { class: "run-table" },
        el("tr", {}, ["", "run", "mode", "seed", "sim s", "status", "restitution", "ideal",
                      "error", "success", "replay"].map((t) => el("th", {}, t))), rows));
  }

  async function open(id) {
    pinned = true;
    try { showRun(await getJSON(`/api/runs/${encodeURIComponent(id)}`)); }
    catch (e) { result.replaceChildren(el("p", { class: "fail" }, e.message)); }
    root.classList.add("open");
  }

  // --- two runs compared: settings that differ, and each figure with both runs overlaid -------
  const CORE_FIGURES = ["forces", "velocity", "position"];  // tried while none are drawn yet

  async function compare() {
    const [ida, idb] = [...chosen].sort();
    let a, b, diff;
    try {
      [a, b, diff] = await Promise.all([
        getJSON(`/api/runs/${encodeURIComponent(ida)}`),
        getJSON(`/api/runs/${encodeURIComponent(idb)}`),
        getJSON("/api/runs/compare?" + new URLSearchParams({ a: ida, b: idb }).toString())]);
    } catch (e) {
      compareBox.replaceChildren(el("p", { class: "fail" }, e.message));
      return;
    }
    const table = diff.settings.length ? el("table", { class: "run-table compare-diff" },
      el("tr", {}, el("th", {}, "setting"), el("th", {}, `A ${a.id}`), el("th", {}, `B ${b.id}`)),
      diff.settings.map((d) => el("tr", {}, el("td", {}, d.key), el("td", {}, JSON.stringify(d.a)),
                                  el("td", {}, JSON.stringify(d.b)))))
      : el("p", {}, "the same settings");
    const names = diff.figures.length ? diff.figures : CORE_FIGURES;
    const overlays = names.map((n) => {
      const img = el("img", { class: "run-plot compare-overlay", src: overlayUrl(a.id, b.id, n),
                              alt: `${n}: ${a.id} and ${b.id} overlaid`, "data-figure": n });
      const box = el("div", { class: "compare-figure" }, el("p", {}, n),
                     el("a", { href: img.getAttribute("src"), target: "_blank" }, img));
      img.onerror = () => box.replaceChildren(el("p", { class: "muted" }, `${n}: neither run has it`));
      return box;
    });
    compareBox.replaceChildren(
      el("h2", {}, `Compare A ${a.id} and B ${b.id}`),
      el("button", { type: "button", onclick: () => compareBox.replaceChildren() }, "close"),
      el("div", { class: "compare-summaries" }, summary(a.metrics, `A ${a.id}`),
         summary(b.metrics, `B ${b.id}`)),
      el("h3", {}, "settings that differ"), table,
      el("h3", {}, "plots overlaid (A solid, B dashed)"), ...overlays);
    root.classList.add("open");
  }

  // --- style --------------------------------------------------------------------------
  document.head.append(el("style", {}, `
    #runs-panel { background: #151b23; border-bottom: 1px solid #2c3642; font-size: .85rem; }
    #runs-bar { display: flex; align-items: center; gap: .6rem; padding: .3rem .8rem; }
    #runs-headline { white-space: nowrap; overflow: hidden; text-overflow: ellipsis; }
    #runs-body { display: none; max-height: 48vh; overflow: auto; padding: 0 .8rem .6rem; }
    #runs-panel.open #runs-body { display: block; }
    #runs-panel h2 { font-size: .95rem; margin: .5rem 0 .2rem; }
    #runs-panel h3 { font-size: .85rem; margin: .4rem 0 .2rem; }
    #runs-panel p { margin: .2rem 0; }
    #runs-panel a { color: #74c0fc; }
    .run-table { border-collapse: collapse; margin: .2rem 0; }
    .run-table td, .run-table th { border: 1px solid #2c3642; padding: .1rem .4rem; text-align: left; }
    .run-plots { display: flex; flex-wrap: wrap; gap: .4rem; }
    .run-plot { max-width: 420px; width: 32%; min-width: 260px; background: #fff; }
    .compare-summaries { display: flex; gap: .8rem; flex-wrap: wrap; }
    .compare-figure .run-plot { width: 90%; max-width: 1100px; }
    .run-warnings { color: #ffd43b; margin: .2rem 0; }
    .muted { color: #adb5bd; }
    .pass { color: #69db7c; } .fail { color: #ff8787; }
    .run-file { margin-right: .6rem; }
  `));

  follow();
  setInterval(follow, 1000);
})();
