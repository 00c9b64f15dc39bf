// touchfem's page: loads the engine (wasm, built from crates/web), a bundled scene and its
// compliance, attaches the canvas's WebGPU device, then runs the haptic ticks and draws frames.
// No physics here: every number comes from the engine. With `press=` in the query it performs
// that press once (as `touchfem poke`), with `run=SECONDS` it runs the scene's own scripts
// (cutting included) for that long; either way it reports `window.touchfemResult` and sets the
// title to `touchfem:done` (or `touchfem:error:REASON`).
import init, { Page } from './touchfem_web.js';

const SCENES = ['fig1', 'fig2', 'palpate', 'incision', 'pinch', 'rub', 'cube', 'mouse', 'phantom'];
const query = new URLSearchParams(location.search);
const sceneName = query.get('scene') || 'fig2';
const press = query.get('press');
const run = query.get('run');
const sphere = Number(query.get('sphere') || 0);
const exact = query.get('exact') === '1';
const wantCache = (query.get('compliance') || 'cache') !== 'compute';

const $ = (id) => document.getElementById(id);
// The page's long tasks (over 50 ms on its one thread: what holds the tab), for the results.
const longTasks = [];
try {
  new PerformanceObserver((list) => {
    for (const e of list.getEntries()) longTasks.push(e.duration);
  }).observe({ type: 'longtask', buffered: true });
} catch (_) { /* a browser without the Long Tasks API reports 0 */ }
const longestTask = () => longTasks.reduce((a, b) => Math.max(a, b), 0);
const status = (text) => { $('status').textContent = text; };
const yieldFrame = () => new Promise((r) => requestAnimationFrame(() => setTimeout(r, 0)));

function fail(reason) {
  const msg = String(reason && reason.message ? reason.message : reason);
  $('message').style.display = 'block';
  $('message').textContent = msg;
  status('stopped');
  document.title = 'touchfem:error:' + msg;
  console.error('touchfem: ' + msg);
}

function setupControls() {
  const sel = $('scene');
  for (const s of SCENES) {
    const o = document.createElement('option');
    o.value = o.textContent = s;
    if (s === sceneName) o.selected = true;
    sel.appendChild(o);
  }
  $('source').value = wantCache ? 'cache' : 'compute';
  const go = () => {
    const q = new URLSearchParams();
    q.set('scene', sel.value);
    if ($('source').value === 'compute') q.set('compliance', 'compute');
    location.search = q.toString();
  };
  sel.onchange = go;
  $('source').onchange = go;
}

async function fetchCache(name) {
  try {
    const r = await fetch(`cache/${name}.tfc`);
    if (!r.ok) return null;
    return new Uint8Array(await r.arrayBuffer());
  } catch (_) {
    return null;
  }
}

// The scene's compliance computed by the engine in a worker: a cache file's bytes, or null
// for a scene the page computes itself.
function computeInWorker(name) {
  return new Promise((resolve, reject) => {
    const w = new Worker(new URL('./worker.js', import.meta.url), { type: 'module' });
    w.onmessage = (e) => {
      w.terminate();
      if (e.data.ok) resolve(e.data.bytes); else reject(new Error(e.data.error));
    };
    w.onerror = (e) => {
      w.terminate();
      reject(new Error(`the compliance worker failed: ${e.message || e}`));
    };
    w.postMessage({ scene: name });
  });
}

function median(v) {
  if (!v.length) return 0;
  const s = [...v].sort((a, b) => a - b);
  const n = s.length;
  return n % 2 ? s[(n - 1) / 2] : 0.5 * (s[n / 2 - 1] + s[n / 2]);
}

async function main() {
  setupControls();
  // A scripted press shows the canvas alone at the page's corner (for screenshots).
  if (press || run) document.body.classList.add('scripted');
  if (!navigator.gpu) {
    throw new Error('this browser has no WebGPU; in Chromium start with --enable-unsafe-webgpu');
  }
  status('loading the engine (wasm)…');
  await init();
  let cache = null;
  if (wantCache) {
    status(`fetching ${sceneName}'s compliance…`);
    cache = await fetchCache(sceneName);
  }
  let t0 = performance.now();
  let page = null;
  let computed = false;
  if (cache) {
    status(`reading ${sceneName}'s compliance (${(cache.length / 1e6).toFixed(1)} MB)…`);
    await yieldFrame();
    try {
      page = new Page(sceneName, cache);
    } catch (e) {
      // A cache that does not fit this build's scene: computed instead, and said so.
      console.warn(`touchfem: cache/${sceneName}.tfc not used (${e.message || e}); computing`);
    }
  }
  if (!page) {
    // Computed by the engine in a worker, so that the tab stays responsive; the page then
    // reads the worker's bytes as it reads a cache file.
    status(`computing ${sceneName}'s compliance in a worker (one thread)…`);
    t0 = performance.now();
    const bytes = await computeInWorker(sceneName);
    status(`reading ${sceneName}'s compliance…`);
    await yieldFrame();
    page = new Page(sceneName, bytes);
    computed = true;
  }
  const complianceMs = performance.now() - t0;
  const source = computed ? 'computed' : page.compliance_source();
  $('n-compliance').textContent = complianceMs.toFixed(0);
  $('about').textContent = page.describe() + ` — compliance ${source}.`;
  status('asking for a WebGPU adapter…');
  await yieldFrame();
  // The adapter as the browser describes it (wgpu's web backend leaves its name empty), and
  // whether it is a software rasteriser (then no MSAA, as the native window on lavapipe).
  let adapter = '';
  let software = false;
  try {
    const a = await navigator.gpu.requestAdapter();
    const i = a && a.info;
    if (i) {
      adapter = [i.vendor, i.architecture, i.device, i.description].filter(Boolean).join(' / ');
      software = !!i.isFallbackAdapter;
    }
  } catch (_) { /* wgpu's request below says what is wrong */ }
  let p;
  try {
    p = await page.attach($('view'), software);
  } catch (e) {
    throw new Error(`${e.message || e}; this browser gave no usable WebGPU adapter (in Chromium start with --enable-unsafe-webgpu)`);
  }
  adapter = adapter || p.adapter();
  status(`${sceneName} on ${adapter}`);
  const info = { complianceMs, source, adapter: adapter || 'WebGPU', software };
  if (press) {
    await scripted(p, info);
  } else if (run) {
    await scriptedRun(p, Number(run), info);
  }
  live(p);
}

// The first object's vertex buffer read back from the GPU (m, x y z per displayed row).
async function readBack(p) {
  p.begin_readback();
  let positions = null;
  for (let i = 0; i < 600 && positions == null; i++) {
    await new Promise((r) => setTimeout(r, 5));
    positions = p.readback_positions();
  }
  if (positions == null) throw new Error('the vertex read-back never completed');
  return positions;
}

// The scripted run: the scene's scripts (and blades: the cutter runs between passes) for
// `seconds` of haptic time, then a few frames and the vertex read-back.
async function scriptedRun(p, seconds, info) {
  const t0 = performance.now();
  const out = JSON.parse(p.run_scripts(seconds));
  const runMs = performance.now() - t0;
  for (let i = 0; i < 3; i++) {
    p.frame();
    await new Promise((r) => requestAnimationFrame(r));
  }
  const positions = await readBack(p);
  window.touchfemResult = {
    scene: sceneName,
    run: seconds,
    ...out,
    run_ms: runMs,
    longest_task_ms: longestTask(),
    adapter: info.adapter,
    compliance_ms: info.complianceMs,
    compliance_source: info.source,
    positions: Array.from(positions),
    rows: Array.from(p.rows()),
    units: { forces: 'N', positions: 'm', time: 's' },
  };
  document.title = 'touchfem:done';
}

// The scripted press: force, one frame, the vertex read-back and the timings.
async function scripted(p, info) {
  const out = JSON.parse(p.scripted_press(press, sphere, exact));
  // Step time: the pointer held where the press ended, 1000 ticks.
  const fin = p.scripted_finger();
  p.set_finger(fin[0], fin[1], fin[2]);
  p.tick(10);
  const ts = performance.now();
  for (let i = 0; i < 10; i++) p.tick(100);
  const stepUs = performance.now() - ts; // ms over 1000 ticks = µs a tick
  p.set_finger(NaN, NaN, NaN);
  p.tick(1);
  // Frames: the press drawn, timed over 30 animation frames.
  const intervals = [];
  const passes = [];
  let last = performance.now();
  for (let i = 0; i < 30; i++) {
    const a = performance.now();
    p.frame();
    passes.push(performance.now() - a);
    await new Promise((r) => requestAnimationFrame(r));
    const now = performance.now();
    intervals.push(now - last);
    last = now;
  }
  const positions = await readBack(p);
  window.touchfemResult = {
    scene: sceneName,
    press,
    force: out.force,
    finger: out.finger,
    active_columns: out.active_columns,
    adapter: info.adapter,
    compliance_ms: info.complianceMs,
    compliance_source: info.source,
    msaa_samples: info.software ? 1 : 4,
    step_us: stepUs,
    frame_ms: median(intervals),
    longest_task_ms: longestTask(),
    record_ms: median(passes),
    positions: Array.from(positions),
    rows: Array.from(p.rows()),
    units: { force: 'N', positions: 'm', finger: 'm' },
  };
  $('n-force').textContent = Math.hypot(...out.force).toFixed(4);
  p.frame();
  await new Promise((r) => requestAnimationFrame(r));
  document.title = 'touchfem:done';
}

// The live page: the pointer presses, the haptic ticks follow the clock, frames follow the
// display, a trace of |F| over the last seconds.
function live(p) {
  const canvas = $('view');
  let mode = null;
  let lastXY = [0, 0];
  const xy = (e) => {
    const r = canvas.getBoundingClientRect();
    return [(e.clientX - r.left) * canvas.width / r.width, (e.clientY - r.top) * canvas.height / r.height];
  };
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    const [x, y] = xy(e);
    lastXY = [x, y];
    if (e.button === 2) {
      mode = 'orbit';
    } else if (e.button === 0 && p.pointer_down(x, y)) {
      mode = 'press';
    }
  });
  canvas.addEventListener('pointermove', (e) => {
    const [x, y] = xy(e);
    if (mode === 'press') p.pointer_drag(x, y);
    if (mode === 'orbit') p.orbit(x - lastXY[0], y - lastXY[1]);
    lastXY = [x, y];
  });
  const up = () => {
    if (mode === 'press') p.pointer_up();
    mode = null;
  };
  canvas.addEventListener('pointerup', up);
  canvas.addEventListener('pointercancel', up);
  const idle = $('status').textContent;
  window.addEventListener('keydown', (e) => {
    if (e.key !== 'b' && e.key !== 'B') return;
    if (mode === 'press') mode = null;
    try {
      const on = p.toggle_blade();
      const [, , , depth] = p.cut_readout();
      status(on ? `blade on (${(depth * 1e3).toFixed(1)} mm deep): left drag cuts · B presses again`
                : idle);
    } catch (err) {
      status(`warning: ${err.message || err}`);
    }
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    p.zoom(-Math.sign(e.deltaY));
  }, { passive: false });

  const trace = [];
  const ctx = $('trace').getContext('2d');
  let lastT = performance.now();
  let carry = 0;
  const frameTimes = [];
  let stepMs = 0;
  let stepTicks = 0;
  let cutMs = 0;
  let shownAt = 0;
  const rate = 1000; // ticks per second: every bundled scene runs its haptic loop at 1 kHz
  const loop = (now) => {
    const dt = Math.min(now - lastT, 100);
    frameTimes.push(now - lastT);
    lastT = now;
    carry += dt * rate / 1000;
    const n = Math.floor(carry);
    carry -= n;
    if (n > 0) {
      const a = performance.now();
      p.tick(n);
      // Summed over the display period: one frame's ticks take less than the browser's
      // timer resolution.
      stepMs += performance.now() - a;
      stepTicks += n;
    }
    try {
      // The cutter's pass over this frame's blade strokes (the engine's cutter, between
      // frames: the page has one thread), then the frame that draws what it cut.
      const c = performance.now();
      if (p.cut() > 0) cutMs = performance.now() - c;
      p.frame();
    } catch (e) {
      fail(e);
      return;
    }
    const [fPointer, fMax] = p.readout();
    trace.push([now, fPointer > 0 ? fPointer : fMax]);
    while (trace.length && now - trace[0][0] > 5000) trace.shift();
    if (now - shownAt > 200) {
      shownAt = now;
      $('n-force').textContent = (fPointer > 0 ? fPointer : fMax).toFixed(3);
      $('n-depth').textContent = (p.depth() * 1e3).toFixed(2);
      $('n-frame').textContent = median(frameTimes.splice(0)).toFixed(1);
      $('n-step').textContent = stepTicks ? (stepMs * 1000 / stepTicks).toFixed(1) : '–';
      stepMs = 0;
      stepTicks = 0;
      const [bodies, tets, , , copies] = p.cut_readout();
      $('n-cut').textContent = bodies > 0
        ? `${copies} copies, ${tets} tets dropped (pass ${cutMs.toFixed(0)} ms)` : '–';
      drawTrace(ctx, trace, now);
    }
    requestAnimationFrame(loop);
  };
  requestAnimationFrame(loop);
}

function drawTrace(ctx, trace, now) {
  const { width: w, height: h } = ctx.canvas;
  ctx.fillStyle = '#fff';
  ctx.fillRect(0, 0, w, h);
  const fMax = Math.max(0.1, ...trace.map((s) => s[1])) * 1.1;
  ctx.strokeStyle = '#ddd';
  ctx.fillStyle = '#666';
  ctx.font = '11px sans-serif';
  ctx.fillText(`${fMax.toFixed(2)} N`, 4, 12);
  ctx.beginPath();
  ctx.moveTo(0, h - 0.5);
  ctx.lineTo(w, h - 0.5);
  ctx.stroke();
  ctx.strokeStyle = '#c22';
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  trace.forEach(([t, f], i) => {
    const x = w - (now - t) / 5000 * w;
    const y = h - f / fMax * (h - 16);
    if (i === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
  });
  ctx.stroke();
}

main().catch(fail);
