// ltlnav dashboard: a hash-routed page polling the JSON API (no build step, no library).
"use strict";

const POLL_MS = 1500;
const CURVE_EVERY = 2; // curves refresh every second mission poll
const ACTIVE = new Set(["queued", "planning", "training", "evaluating"]);
const KEY_STORE = "ltlnav.apiKey";

let generation = 0; // bumped on every route change; stale poll loops stop themselves

// ---------------------------------------------------------------- DOM and formatting

function h(tag, attrs, ...children) {
  const el = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (name.startsWith("on")) el.addEventListener(name.slice(2), value);
    else el.setAttribute(name, value === true ? "" : String(value));
  }
  for (const child of children.flat()) {
    if (child === null || child === undefined || child === false) continue;
    el.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return el;
}

const SVG_NS = "http://www.w3.org/2000/svg";
function s(tag, attrs, text) {
  const el = document.createElementNS(SVG_NS, tag);
  for (const [name, value] of Object.entries(attrs || {})) el.setAttribute(name, String(value));
  if (text !== undefined) el.textContent = text;
  return el;
}

function pct(value) {
  return value === null || value === undefined ? "–" : `${(100 * value).toFixed(1)} %`;
}

function num(value, digits = 2) {
  return value === null || value === undefined ? "–" : Number(value).toFixed(digits);
}

function duration(seconds) {
  if (seconds === null || seconds === undefined) return "–";
  const t = Math.max(0, Math.round(seconds));
  if (t < 60) return `${t} s`;
  if (t < 3600) return `${Math.floor(t / 60)} min ${t % 60} s`;
  return `${Math.floor(t / 3600)} h ${Math.floor((t % 3600) / 60)} min`;
}

function when(iso) {
  if (!iso) return "–";
  const date = new Date(iso);
  return Number.isNaN(date.getTime()) ? iso : date.toLocaleString();
}

function badge(status) {
  return h("span", { class: `badge ${status}` }, status);
}

function table(headers, rows, numeric = []) {
  const head = h("tr", {}, headers.map((name, i) =>
    h("th", { scope: "col", class: numeric.includes(i) ? "num" : null }, name)));
  const body = rows.map((cells) => h("tr", {}, cells.map((cell, i) =>
    h("td", { class: numeric.includes(i) ? "num" : null }, cell))));
  return h("table", {}, h("thead", {}, head), h("tbody", {}, body));
}

// ---------------------------------------------------------------- API access

class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

function apiKey() {
  return localStorage.getItem(KEY_STORE) || "";
}

/** The API's `detail` as one readable message (string, or a list of {loc, msg}). */
function describe(detail, status) {
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    return detail.map((item) => {
      if (typeof item !== "object" || item === null) return String(item);
      const loc = Array.isArray(item.loc) ? item.loc.filter((p) => p !== "body").join(".") : "";
      return loc ? `${loc}: ${item.msg}` : String(item.msg);
    }).join("\n");
  }
  if (detail !== undefined) return JSON.stringify(detail);
  return `HTTP ${status}`;
}

async function api(path, options = {}) {
  const headers = new Headers(options.headers || {});
  const key = apiKey();
  if (key) headers.set("Authorization", `Bearer ${key}`);
  let response;
  try {
    response = await fetch(path, { ...options, headers });
  } catch (error) {
    throw new ApiError(0, `cannot reach the server (${error.message})`);
  }
  if (!response.ok) {
    let detail;
    try {
      detail = (await response.json()).detail;
    } catch {
      detail = undefined;
    }
    throw new ApiError(response.status, `${response.status}: ${describe(detail, response.status)}`);
  }
  return response;
}

async function apiJson(path, options) {
  return (await api(path, options)).json();
}

function showError(message) {
  const banner = document.getElementById("error");
  banner.textContent = message || "";
  banner.hidden = !message;
}

// ---------------------------------------------------------------- progress bars

// A running job's estimated time left, or the evaluation it runs once its training ended.
function timeLeft(job) {
  return job.eta_seconds == null && job.reason ? job.reason : `ETA ${duration(job.eta_seconds)}`;
}

function progressBars(jobs) {
  if (!jobs || jobs.length === 0) return h("span", { class: "muted" }, "no sub-tasks yet");
  const grid = h("div", { class: "progress" });
  for (const job of jobs) {
    const budget = Math.max(job.budget || 0, 1);
    const share = Math.min(1, (job.steps_done || 0) / budget);
    const label = `sub-task ${job.index}`;
    grid.append(
      h("span", { class: "label" }, label),
      h("div", {
        class: `bar ${job.status}`,
        role: "progressbar",
        "aria-label": label,
        "aria-valuemin": 0,
        "aria-valuemax": job.budget,
        "aria-valuenow": job.steps_done,
        "data-subtask": job.index,
      }, h("span", { style: `width: ${(100 * share).toFixed(1)}%` })),
      h("span", { class: "detail" },
        `${job.steps_done}/${job.budget} steps · ${job.status} · success ${pct(job.success_rate)}` +
        (job.status === "running" ? ` · ${timeLeft(job)}` : "")),
    );
  }
  return grid;
}

// ---------------------------------------------------------------- missions list + submit form

function submitForm(examples) {
  const message = h("p", { id: "submit-error", class: "error-text", role: "alert" });
  const select = h("select", { id: "example", name: "example" },
    examples.map((e) => h("option", { value: e.name }, `${e.name} (${e.robot}): ${e.task}`)),
    h("option", { value: "" }, "custom mission (JSON below)"));
  const text = h("textarea", {
    id: "mission-json", name: "mission-json", spellcheck: "false",
    placeholder: '{"name": "...", "task": "...", "robot": {...}, "world": {...}}',
  });
  const button = h("button", { type: "submit", id: "submit" }, "Submit mission");

  async function onsubmit(event) {
    event.preventDefault();
    message.textContent = "";
    let body;
    if (select.value) {
      body = JSON.stringify({ example: select.value });
    } else {
      try {
        JSON.parse(text.value);
      } catch (error) {
        message.textContent = `mission JSON: ${error.message}`;
        return;
      }
      body = text.value;
    }
    button.disabled = true;
    try {
      const created = await apiJson("/missions", {
        method: "POST", body, headers: { "Content-Type": "application/json" },
      });
      location.hash = `#/missions/${created.id}`;
    } catch (error) {
      message.textContent = error.message;
    } finally {
      button.disabled = false;
    }
  }

  return h("form", { class: "card", id: "submit-form", onsubmit },
    h("h2", {}, "New mission"),
    h("div", { class: "row" }, h("label", { for: "example" }, "Mission"), select),
    h("label", { for: "mission-json" }, "Mission document (JSON, used when \"custom\" is chosen)"),
    text,
    h("div", { class: "row" }, button),
    message);
}

const PAGE_SIZE = 50;

async function missionsView(gen, view, offset) {
  const list = h("div", { id: "missions" }, h("p", { class: "muted" }, "loading…"));
  let examples = [];
  try {
    examples = (await apiJson("/examples")).examples;
  } catch (error) {
    showError(`examples: ${error.message}`);
  }
  if (gen !== generation) return;
  view.replaceChildren(h("h1", {}, "Missions"), submitForm(examples), h("section", { class: "card" },
    h("h2", {}, "Recent missions"), list));

  let shown = ""; // re-render only on change: keeps focus and selection in the table
  while (gen === generation) {
    try {
      const page = await apiJson(`/missions?limit=${PAGE_SIZE}&offset=${offset}`);
      if (gen !== generation) return;
      const text = JSON.stringify(page);
      if (text !== shown) list.replaceChildren(missionTable(page));
      shown = text;
      showError("");
    } catch (error) {
      if (gen !== generation) return;
      showError(`missions: ${error.message}`);
    }
    await sleep(POLL_MS);
  }
}

function missionTable(page) {
  if (page.items.length === 0) {
    return h("p", { class: "muted", id: "no-missions" },
      page.offset > 0 ? "No missions on this page." : "No missions yet.",
      page.offset > 0 ? h("a", { href: "#/" }, " Newest missions") : null);
  }
  const rows = page.items.map((m) => [
    h("a", { href: `#/missions/${m.id}` }, m.name),
    h("div", {}, badge(m.status), m.reason
      ? h("div", { class: ACTIVE.has(m.status) ? "reason news" : "reason" }, m.reason) : null),
    m.jobs ? progressBars(m.jobs) : h("span", { class: "muted" }, "–"),
    when(m.created_at),
  ]);
  const last = page.offset + page.items.length;
  const pager = h("nav", { class: "row", "aria-label": "Mission pages" },
    h("span", { class: "muted" }, `${page.offset + 1}–${last} of ${page.total}, newest first`),
    page.offset > 0
      ? h("a", { href: `#/?offset=${Math.max(0, page.offset - page.limit)}` }, "← newer") : null,
    last < page.total ? h("a", { href: `#/?offset=${last}` }, "older →") : null);
  return h("div", {}, table(["Mission", "Status", "Sub-tasks", "Created"], rows), pager);
}

// ---------------------------------------------------------------- mission view

function planSection(mission, image) {
  const plan = mission.plan;
  if (!plan) return h("p", { class: "muted" }, "Not planned yet.");
  const summary = table(
    ["automaton states", "pruned states", "prefix length", "suffix length", "cost", "planning time"],
    [[plan.automaton_states, plan.pruned_states, num(plan.prefix_length), num(plan.suffix_length),
      num(plan.cost), `${num(plan.seconds)} s`]], [0, 1, 2, 3, 4, 5]);
  const subtasks = table(["sub-task", "phase", "goal", "length", "r-balls", "ball radius"],
    (plan.subtasks || []).map((t) => [t.index, t.phase, t.goal || "(end of guide)", num(t.length), t.balls,
      num(t.r_ball)]), [0, 3, 4, 5]);
  return h("div", {}, image, summary, h("h3", {}, "Sub-tasks"), subtasks);
}

/** A finished job's wall time; hovering shows where it went, largest part first. */
function jobTime(job) {
  if (job.seconds === null || job.seconds === undefined) return "–";
  const parts = Object.entries(job.time_by_part || {}).sort((a, b) => b[1] - a[1]);
  const split = parts.map(([name, seconds]) => `${name}: ${duration(seconds)}`).join("\n");
  return h("span", { class: "job-time", title: split || null }, duration(job.seconds));
}

function jobsTable(jobs) {
  if (!jobs || jobs.length === 0) return h("p", { class: "muted" }, "No training jobs yet.");
  const rows = jobs.map((j) => {
    const f = j.final || {};
    return [j.index, badge(j.status), `${j.steps_done}/${j.budget}`, pct(j.success_rate),
      j.status === "running" ? timeLeft(j) : "–", j.attempts,
      j.final ? f.episodes : "–", j.final ? pct(f.success_rate) : "–",
      j.final ? pct(f.collision_rate) : "–", j.final ? pct(f.timeout_rate) : "–",
      j.final ? pct(f.rejected_rate) : "–", j.final ? num(f.mean_steps_to_goal, 1) : "–",
      jobTime(j), j.reason || ""];
  });
  return h("div", { id: "jobs" }, table(
    ["sub-task", "status", "steps", "latest success", "ETA", "attempts", "eval episodes",
      "success", "collisions", "timeouts", "rejected", "steps to goal", "time", "reason"],
    rows, [0, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]));
}

function repairsTable(repairs, rounds) {
  if (!repairs || repairs.length === 0) return h("div", { id: "repairs" });
  const judged = new Map((rounds || []).map((r) => [r.round, r]));
  const rows = repairs.map((j) => {
    const r = judged.get(j.round);
    const verdict = r ? `${pct(r.success_before)} → ${pct(r.success_after)}, `
      + (r.kept ? "kept" : "not kept") : "–";
    return [j.round, j.index, badge(j.status), `${j.steps_done}/${j.budget}`,
      pct(j.success_rate), j.final ? pct(j.final.success_rate) : "–", verdict, j.reason || ""];
  });
  return h("div", { id: "repairs" }, h("h3", {}, "Hand-over repair"), table(
    ["round", "sub-task", "status", "steps", "latest success", "success", "mission", "reason"],
    rows, [0, 1, 3, 4, 5]));
}

function evaluationSection(evaluation) {
  if (!evaluation) return h("p", { class: "muted" }, "Not evaluated yet.");
  const summary = table(
    ["rollouts", "suffix cycles", "success", "collisions", "timeouts", "rejected", "mean steps"],
    [[evaluation.episodes, evaluation.cycles, pct(evaluation.success_rate),
      pct(evaluation.collision_rate), pct(evaluation.timeout_rate), pct(evaluation.rejected_rate),
      num(evaluation.mean_steps, 1)]], [0, 1, 2, 3, 4, 5, 6]);
  const failures = Object.entries(evaluation.failures || {})
    .sort((a, b) => Number(a[0]) - Number(b[0]))
    .map(([where, kinds]) => [where, kinds.collision || 0, kinds.timeout || 0, kinds.rejected || 0]);
  return h("div", { id: "evaluation" }, summary, h("h3", {}, "Failures by sub-task"),
    failures.length
      ? table(["sub-task", "collisions", "timeouts", "rejected"], failures, [0, 1, 2, 3])
      : h("p", { class: "muted" }, "None."));
}

/** Success rate against steps as an inline SVG line chart. */
function curveChart(index, points, budget) {
  const W = 320, H = 170, L = 36, R = 10, T = 10, B = 30;
  const maxX = Math.max(budget || 0, ...points.map((p) => p.steps), 1);
  const x = (v) => L + ((W - L - R) * v) / maxX;
  const y = (v) => T + (H - T - B) * (1 - v);
  const svg = s("svg", {
    viewBox: `0 0 ${W} ${H}`, role: "img",
    "aria-label": `sub-task ${index}: success rate against training steps, ${points.length} evaluations`,
  });
  for (const v of [0, 0.5, 1]) {
    svg.append(s("line", { class: "grid", x1: L, x2: W - R, y1: y(v), y2: y(v) }));
    svg.append(s("text", { x: L - 4, y: y(v) + 3, "text-anchor": "end" }, `${v * 100}%`));
  }
  svg.append(s("line", { class: "axis", x1: L, x2: L, y1: T, y2: H - B }));
  svg.append(s("line", { class: "axis", x1: L, x2: W - R, y1: H - B, y2: H - B }));
  svg.append(s("text", { x: L, y: H - B + 14 }, "0"));
  svg.append(s("text", { x: W - R, y: H - B + 14, "text-anchor": "end" }, String(maxX)));
  svg.append(s("text", { x: (L + W - R) / 2, y: H - 4, "text-anchor": "middle" }, "steps"));
  if (points.length > 0) {
    const d = points.map((p, i) => `${i ? "L" : "M"}${x(p.steps).toFixed(1)},${y(p.success_rate).toFixed(1)}`);
    svg.append(s("path", { class: "line", d: d.join(" ") }));
    for (const p of points) {
      const dot = s("circle", { class: "dot", cx: x(p.steps), cy: y(p.success_rate), r: 2.5 });
      dot.append(s("title", {}, `${p.steps} steps: ${pct(p.success_rate)} over ${p.episodes} episodes`));
      svg.append(dot);
    }
  }
  return h("figure", { class: "curve", "data-subtask": index },
    h("figcaption", {}, `Sub-task ${index}`), svg,
    points.length ? null : h("p", { class: "muted" }, "no evaluation yet"));
}

async function loadCurves(mission) {
  const urls = (mission.links && mission.links.curves) || [];
  const budgets = new Map((mission.jobs || []).map((j) => [j.index, j.budget]));
  const curves = await Promise.all(urls.map((url) => apiJson(url)));
  return h("div", { class: "curves", id: "curves" },
    curves.map((c) => curveChart(c.index, c.points, budgets.get(c.index))));
}

/** The named members of a zip blob as PNG blobs (stored or deflated; no ZIP64). */
async function zipPictures(blob, names) {
  const bytes = new Uint8Array(await blob.arrayBuffer());
  const view = new DataView(bytes.buffer);
  let end = bytes.length - 22;
  while (end >= 0 && view.getUint32(end, true) !== 0x06054b50) end -= 1;
  if (end < 0) throw new Error("the bundle is not a zip file");
  const found = new Map();
  let at = view.getUint32(end + 16, true);
  for (let i = 0; i < view.getUint16(end + 10, true); i += 1) {
    if (view.getUint32(at, true) !== 0x02014b50) throw new Error("corrupt zip directory");
    const method = view.getUint16(at + 10, true);
    const size = view.getUint32(at + 20, true);
    const nameLength = view.getUint16(at + 28, true);
    const skip = nameLength + view.getUint16(at + 30, true) + view.getUint16(at + 32, true);
    const name = new TextDecoder().decode(bytes.subarray(at + 46, at + 46 + nameLength));
    const local = view.getUint32(at + 42, true);
    at += 46 + skip;
    if (!names.includes(name) || (method !== 0 && method !== 8)) continue;
    const start = local + 30 + view.getUint16(local + 26, true) + view.getUint16(local + 28, true);
    let data = new Blob([bytes.subarray(start, start + size)]);
    if (method === 8) {
      data = await new Response(data.stream().pipeThrough(new DecompressionStream("deflate-raw"))).blob();
    }
    found.set(name, new Blob([data], { type: "image/png" }));
  }
  return found;
}

const BUNDLE_PICTURES = [
  ["rollout.png", "whole-mission rollouts of the concatenated policy"],
  ["learning_curves.png", "learning curves of every sub-task, as bundled"],
];

async function bundleSection(blob, name) {
  const pictures = await zipPictures(blob, BUNDLE_PICTURES.map(([file]) => file));
  return h("div", { class: "pictures", id: "bundle-pictures" }, BUNDLE_PICTURES
    .filter(([file]) => pictures.has(file))
    .map(([file, alt]) => h("figure", {},
      h("figcaption", {}, file),
      h("img", { class: "plan-img", alt: `${name}: ${alt}`, src: URL.createObjectURL(pictures.get(file)) }))));
}

async function blobUrl(path) {
  return URL.createObjectURL(await (await api(path)).blob());
}

async function download(mission, status, bundle) {
  status.textContent = "";
  try {
    const url = URL.createObjectURL(bundle.blob || await (await api(mission.links.bundle)).blob());
    const link = h("a", { href: url, download: `${mission.name}-${mission.id}.zip` });
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  } catch (error) {
    status.textContent = `download: ${error.message}`;
  }
}

async function cancel(mission, status, button) {
  status.textContent = "";
  button.disabled = true;
  try {
    await api(mission.links.cancel, { method: "POST" });
  } catch (error) {
    status.textContent = `cancel: ${error.message}`;
    button.disabled = false;
  }
}

async function missionView(gen, view, id) {
  const parts = {
    header: h("div", {}),
    actions: h("div", { class: "row" }),
    status: h("p", { class: "error-text", role: "alert", id: "action-error" }),
    plan: h("div", {}),
    jobs: h("div", { id: "training" }),
    curves: h("div", {}, h("p", { class: "muted" }, "No curves yet.")),
    evaluation: h("div", {}),
    rollouts: h("div", {}, h("p", { class: "muted" }, "Shown when the bundle is ready.")),
  };
  const bundle = { blob: null };
  view.replaceChildren(
    h("p", {}, h("a", { href: "#/" }, "← all missions")),
    h("section", { class: "card" }, parts.header, parts.actions, parts.status),
    h("section", { class: "card" }, h("h2", {}, "Plan"), parts.plan),
    h("section", { class: "card" }, h("h2", {}, "Training"), parts.jobs,
      h("h3", {}, "Learning curves (success rate against steps)"), parts.curves),
    h("section", { class: "card" }, h("h2", {}, "Mission evaluation"), parts.evaluation,
      h("h3", {}, "Rollout pictures (from the bundle)"), parts.rollouts),
  );
  let image = null;
  let polls = 0;
  let settled = 0; // polls after a final status (the plan picture may still be coming)
  let shown = "";
  while (gen === generation) {
    let mission;
    try {
      mission = await apiJson(`/missions/${encodeURIComponent(id)}`);
      showError("");
    } catch (error) {
      if (gen !== generation) return;
      showError(`mission ${id}: ${error.message}`);
      if (error.status === 404 || error.status === 401) return;
      await sleep(POLL_MS);
      continue;
    }
    if (gen !== generation) return;
    if (!image && mission.plan && mission.links.plan_png) {
      try {
        image = h("img", { class: "plan-img", alt: `plan of ${mission.name}: lasso path and sub-task goals`,
          src: await blobUrl(mission.links.plan_png) });
      } catch {
        image = null; // the picture is written just after the plan; retried on the next poll
      }
    }
    const text = JSON.stringify(mission) + Boolean(image);
    if (text !== shown) renderMission(mission, parts, image, bundle);
    shown = text;
    if (mission.status === "done" && !bundle.blob) {
      try {
        bundle.blob = await (await api(mission.links.bundle)).blob();
        parts.rollouts.replaceChildren(await bundleSection(bundle.blob, mission.name));
      } catch (error) {
        parts.status.textContent = `bundle: ${error.message}`;
      }
    }
    const active = ACTIVE.has(mission.status);
    if (polls % CURVE_EVERY === 0 || !active) {
      try {
        const curves = await loadCurves(mission);
        if (gen === generation && curves.childElementCount) parts.curves.replaceChildren(curves);
      } catch (error) {
        parts.status.textContent = `curves: ${error.message}`;
      }
    }
    polls += 1;
    if (!active) settled += 1;
    if (!active && (image || !mission.plan || settled > 3)) return;
    await sleep(POLL_MS);
  }
}

function renderMission(mission, parts, image, bundle) {
  parts.header.replaceChildren(...[
    h("h1", {}, mission.name, " ", h("span", { id: "mission-status" }, badge(mission.status))),
    h("p", { class: "muted" }, `${mission.id} · robot ${mission.robot} · created ${when(mission.created_at)}` +
      ` · updated ${when(mission.updated_at)}`),
    h("p", {}, h("code", {}, mission.task)),
    mission.reason ? h("p", { class: ACTIVE.has(mission.status) ? "news" : "error-text",
      id: "mission-reason" }, mission.reason) : null,
    mission.cancel_requested && ACTIVE.has(mission.status)
      ? h("p", { class: "muted" }, "Cancel requested: running sub-tasks stop at their next check.")
      : null,
  ].filter(Boolean));
  const cancelButton = h("button", { type: "button", class: "danger", id: "cancel",
    disabled: !ACTIVE.has(mission.status) },
  "Cancel");
  cancelButton.addEventListener("click", () => cancel(mission, parts.status, cancelButton));
  const downloadButton = h("button", { type: "button", id: "download",
    disabled: mission.status !== "done", onclick: () => download(mission, parts.status, bundle) },
  "Download bundle");
  parts.actions.replaceChildren(downloadButton, cancelButton);
  parts.plan.replaceChildren(planSection(mission, image));
  parts.jobs.replaceChildren(progressBars(mission.jobs), jobsTable(mission.jobs),
    repairsTable(mission.repairs, mission.repair_rounds));
  parts.evaluation.replaceChildren(evaluationSection(mission.evaluation));
}

// ---------------------------------------------------------------- routing

function sleep(ms) {
  return new Promise((resolve) => setTimeout(resolve, ms));
}

function route() {
  generation += 1;
  const gen = generation;
  showError("");
  const view = document.getElementById("view");
  const match = location.hash.match(/^#\/missions\/([^/]+)$/);
  const offset = Number((location.hash.match(/[?&]offset=(\d+)/) || [])[1] || 0);
  if (match) missionView(gen, view, decodeURIComponent(match[1]));
  else missionsView(gen, view, offset);
}

function setUpKey() {
  const form = document.getElementById("key-form");
  const input = document.getElementById("api-key");
  input.value = apiKey();
  form.addEventListener("submit", (event) => {
    event.preventDefault();
    if (input.value.trim()) localStorage.setItem(KEY_STORE, input.value.trim());
    else localStorage.removeItem(KEY_STORE);
    route();
  });
}

window.addEventListener("hashchange", route);
window.addEventListener("DOMContentLoaded", () => {
  setUpKey();
  route();
});
