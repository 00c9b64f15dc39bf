#!/usr/bin/env node
// Drives a real headless Chromium over the DevTools protocol (CDP) to run one touchfem web page
// and report what it did. Zero dependencies: Node >= 18 and Debian's chromium
// (scripts/ensure-chromium.sh installs both).
//
//   node scripts/web-driver.mjs --dir DIR --page 'index.html?scene=fig2&press=...'
//        [--size 640x480] [--timeout-s 120] [--screenshot OUT.png] [--no-webgpu]
//        [--chromium PATH] [--chromium-arg FLAG]... [--verbose]
//
// It serves DIR itself over HTTP on 127.0.0.1 (ephemeral port), starts Chromium headless with a
// fresh profile, opens http://127.0.0.1:PORT/PAGE and polls document.title until the page sets it
// to "touchfem:done" or "touchfem:error:<message>" (or --timeout-s passes). Then it reads
// window.touchfemResult, optionally takes a PNG screenshot, and prints ONE JSON object on stdout:
//
//   {"title": ..., "result": <window.touchfemResult or null>, "errors": [...], "warnings": [...],
//    "body_text": <document.body.innerText, at most 2000 chars>, "elapsed_ms": ...}
//
// errors: console.error messages, uncaught exceptions and Log-domain errors (network failures,
// WebGPU validation errors reported by Chromium, ...); warnings: console.warn and Log warnings.
//
// The result and the body text are read (and the screenshot taken) whatever the outcome, so a
// timed-out or failed page still shows how far it got.
//
// Exit status: 0 title is touchfem:done; 3 the page reported touchfem:error:...; 4 timeout;
// 1 driver failure (Chromium would not start, the page crashed, the screenshot failed, ...), with a
// one-line "error: ..." on stderr (the JSON is still printed when the page had been loaded);
// 2 usage (no arguments: the usage text).
//
// Options: --size WxH is the viewport (and screenshot) in CSS pixels at scale 1; --timeout-s
// counts from the driver's start; --no-webgpu leaves out the WebGPU flags below (the page then
// finds no adapter: a test of its fallback message); --chromium picks the binary (default: Debian's
// /usr/lib/chromium/chromium, else chromium on PATH); --chromium-arg adds one more Chromium flag
// (repeatable); --verbose copies Chromium's own log to stderr.
//
// The DevTools transport is --remote-debugging-pipe: CDP messages are JSON texts, each ended by a
// NUL byte, written to Chromium's fd 3 and read from its fd 4. No port, no WebSocket, no npm.

import { spawn } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';

const USAGE = `usage: node scripts/web-driver.mjs --dir DIR --page 'index.html?scene=fig2&press=...'
         [--size 640x480] [--timeout-s 120] [--screenshot OUT.png] [--no-webgpu]
         [--chromium PATH] [--chromium-arg FLAG]... [--verbose]
Serves DIR on 127.0.0.1, opens PAGE in headless Chromium, waits for document.title to become
"touchfem:done" or "touchfem:error:...", prints {"title","result","errors","warnings",
"body_text","elapsed_ms"} as JSON. Exit 0 done, 3 page error, 4 timeout, 1 driver failure.`;

const T0 = Date.now();

// ---------------------------------------------------------------------------------------------
// Arguments
// ---------------------------------------------------------------------------------------------

function parseArgs(argv) {
  if (argv.length === 0) throw new UsageError(null);
  const o = { dir: null, page: null, width: 640, height: 480, timeoutS: 120, screenshot: null,
    webgpu: true, chromium: null, chromiumArgs: [], verbose: false };
  const need = (i) => {
    if (i + 1 >= argv.length) throw new UsageError(`${argv[i]} needs a value`);
    return argv[i + 1];
  };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    switch (a) {
      case '--dir': o.dir = need(i); i++; break;
      case '--page': o.page = need(i); i++; break;
      case '--size': {
        const m = /^(\d+)x(\d+)$/.exec(need(i)); i++;
        if (!m || +m[1] === 0 || +m[2] === 0) throw new UsageError('--size wants WIDTHxHEIGHT, e.g. 640x480');
        o.width = +m[1]; o.height = +m[2];
        break;
      }
      case '--timeout-s': o.timeoutS = Number(need(i)); i++;
        if (!(o.timeoutS > 0)) throw new UsageError('--timeout-s wants a positive number');
        break;
      case '--screenshot': o.screenshot = need(i); i++; break;
      case '--no-webgpu': o.webgpu = false; break;
      case '--chromium': o.chromium = need(i); i++; break;
      case '--chromium-arg': o.chromiumArgs.push(need(i)); i++; break;
      case '--verbose': o.verbose = true; break;
      case '-h': case '--help': throw new UsageError(null);
      default: throw new UsageError(`unknown argument ${a}`);
    }
  }
  if (!o.dir || !o.page) throw new UsageError('--dir and --page are required');
  return o;
}

class UsageError extends Error {}

// ---------------------------------------------------------------------------------------------
// Static HTTP server for DIR
// ---------------------------------------------------------------------------------------------

const MIME = {
  '.html': 'text/html; charset=utf-8',
  '.htm': 'text/html; charset=utf-8',
  '.js': 'application/javascript; charset=utf-8',
  '.mjs': 'application/javascript; charset=utf-8',
  '.wasm': 'application/wasm', // required for WebAssembly.instantiateStreaming
  '.json': 'application/json; charset=utf-8',
  '.png': 'image/png',
  '.css': 'text/css; charset=utf-8',
  '.bin': 'application/octet-stream',
  '.tfc': 'application/octet-stream',
  '.wgsl': 'text/plain; charset=utf-8',
  '.txt': 'text/plain; charset=utf-8',
  '.svg': 'image/svg+xml',
  '.ico': 'image/x-icon',
};

function startServer(root) {
  root = fs.realpathSync(root);
  const server = http.createServer((req, res) => {
    const send = (code, body, type = 'text/plain; charset=utf-8') => {
      res.writeHead(code, { 'Content-Type': type, 'Cache-Control': 'no-store' });
      res.end(body);
    };
    if (req.method !== 'GET' && req.method !== 'HEAD') return send(405, 'method not allowed\n');
    let rel;
    try {
      rel = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    } catch {
      return send(400, 'bad request\n');
    }
    if (rel.includes('\0')) return send(400, 'bad request\n');
    // Normalizing against "/" first drops every "..": the path cannot leave DIR (checked again
    // below). Symbolic links inside DIR are followed on purpose (e.g. to a wasm build output).
    let file = path.join(root, path.posix.normalize('/' + rel));
    if (file !== root && !file.startsWith(root + path.sep)) return send(404, 'not found\n');
    try {
      if (fs.statSync(file).isDirectory()) file = path.join(file, 'index.html');
      fs.accessSync(file, fs.constants.R_OK);
    } catch {
      // Browsers ask for /favicon.ico by themselves: no console error for a page that has none.
      if (rel === '/favicon.ico') return send(204, '');
      return send(404, 'not found\n');
    }
    const type = MIME[path.extname(file).toLowerCase()];
    if (!type) return send(404, 'not found (unknown type)\n');
    fs.readFile(file, (err, data) => {
      if (err) return send(404, 'not found\n');
      res.writeHead(200, { 'Content-Type': type, 'Content-Length': data.length,
        'Cache-Control': 'no-store' });
      res.end(req.method === 'HEAD' ? undefined : data);
    });
  });
  return new Promise((resolve, reject) => {
    server.once('error', reject);
    server.listen(0, '127.0.0.1', () => resolve(server));
  });
}

// ---------------------------------------------------------------------------------------------
// Chromium
// ---------------------------------------------------------------------------------------------

function findChromium(explicit) {
  if (explicit) return explicit;
  // Prefer Debian's real binary over the /usr/bin/chromium shell wrapper: the wrapper adds flags
  // of its own (--load-extension=..., --enable-remote-extensions) and prints shell noise.
  const candidates = ['/usr/lib/chromium/chromium'];
  for (const name of ['chromium', 'chromium-browser', 'google-chrome', 'google-chrome-stable']) {
    for (const dir of (process.env.PATH || '').split(':')) if (dir) candidates.push(path.join(dir, name));
  }
  for (const c of candidates) {
    try { fs.accessSync(c, fs.constants.X_OK); return c; } catch { /* next */ }
  }
  throw new Error('no chromium found (run scripts/ensure-chromium.sh, or pass --chromium PATH)');
}

function chromiumArgs(o, profileDir) {
  const args = [
    '--headless=new', // the full browser headless (old headless is a separate binary nowadays)
    '--remote-debugging-pipe', // CDP over fds 3/4
    `--user-data-dir=${profileDir}`, // fresh profile: no state leaks between runs
    '--no-first-run',
    '--no-default-browser-check',
    '--disable-background-networking',
    '--disable-extensions',
    '--disable-component-update',
    '--disable-sync',
    '--hide-scrollbars',
    '--mute-audio',
    `--window-size=${o.width},${o.height}`,
  ];
  // Chromium's sandbox cannot start as root (it refuses to run at all); containers run as root.
  if (typeof process.getuid === 'function' && process.getuid() === 0) args.push('--no-sandbox');
  // Chromium puts its shared memory in /dev/shm; a small one (Docker's default is 64 MiB) crashes
  // renderers and the GPU process. Debian's wrapper does the same check.
  try {
    const st = fs.statfsSync('/dev/shm');
    if (st.bavail * st.bsize < 1 << 30) args.push('--disable-dev-shm-usage');
  } catch { /* no /dev/shm: nothing to do */ }
  if (o.webgpu) {
    // The minimal set that gives both a WebGPU adapter and a canvas that reaches the screenshot,
    // on a machine without a GPU (Chromium 156, Debian bookworm). Each was found necessary by
    // leaving it out:
    args.push(
      // WebGPU is off on Linux unless the GPU is on Chromium's allow list (never true here):
      // without this navigator.gpu.requestAdapter() returns null.
      '--enable-unsafe-webgpu',
      // Dawn's Vulkan backend (the only one on Linux) is behind this feature, and so is the
      // Vulkan interop the canvas needs; without it the canvas fails (see --use-angle).
      '--enable-features=Vulkan',
      // Use the SwiftShader software Vulkan bundled with Chromium (libvk_swiftshader.so), not the
      // system loader's ICDs (lavapipe, real drivers): the same adapter, "google / swiftshader",
      // on every machine, hence reproducible numbers.
      '--use-vulkan=swiftshader',
      // The compositor's GL through ANGLE on SwiftShader as well (=vulkan works the same). Without
      // it the adapter and compute passes work, but the canvas swap chain cannot be shared with
      // the compositor ("Could not find SharedImageBackingFactory ... WebgpuSwapChainTexture"),
      // the GPU process drops the device, and the page sees "A valid external Instance
      // reference no longer exists." from getCurrentTexture()/configure().
      '--use-angle=swiftshader',
    );
    // Not needed (tested): --use-webgpu-adapter=swiftshader, --enable-unsafe-swiftshader (the
    // adapter is SwiftShader anyway, and WebGL is not used). --enable-webgpu-developer-features
    // would fill GPUAdapterInfo.description ("SwiftShader Device (Subzero)"); pass it with
    // --chromium-arg when wanted.
  }
  return args.concat(o.chromiumArgs);
}

// The CDP connection over the pipe. send() returns a promise of the reply's result; events go to
// the onEvent callback as (method, params, sessionId).
class Cdp {
  constructor(writable, readable, onEvent) {
    this.w = writable;
    this.nextId = 1;
    this.pending = new Map();
    this.onEvent = onEvent;
    this.closed = false;
    // Messages can be split across chunks and can be many megabytes (a returnByValue of a big
    // result, a screenshot): keep the chunks of the unfinished message in a list and only join
    // them once its terminating NUL arrives (no quadratic re-concatenation).
    let parts = [];
    readable.on('data', (chunk) => {
      let start = 0;
      for (;;) {
        const nul = chunk.indexOf(0, start);
        if (nul < 0) {
          if (start < chunk.length) parts.push(chunk.subarray(start));
          break;
        }
        parts.push(chunk.subarray(start, nul));
        const text = parts.length === 1 ? parts[0].toString('utf8') : Buffer.concat(parts).toString('utf8');
        parts = [];
        start = nul + 1;
        this.dispatch(text);
      }
    });
    const fail = (why) => {
      if (this.closed) return;
      this.closed = true;
      for (const { reject, method } of this.pending.values()) reject(new Error(`${method}: ${why}`));
      this.pending.clear();
    };
    readable.on('end', () => fail('DevTools pipe closed (chromium exited?)'));
    readable.on('error', (e) => fail(`DevTools pipe error: ${e.message}`));
    writable.on('error', (e) => fail(`DevTools pipe error: ${e.message}`));
  }

  dispatch(text) {
    let msg;
    try { msg = JSON.parse(text); } catch { return; }
    if (msg.id !== undefined) {
      const p = this.pending.get(msg.id);
      if (!p) return;
      this.pending.delete(msg.id);
      if (msg.error) p.reject(new Error(`${p.method}: ${msg.error.message}${msg.error.data ? ' (' + msg.error.data + ')' : ''}`));
      else p.resolve(msg.result);
    } else if (msg.method) {
      this.onEvent(msg.method, msg.params || {}, msg.sessionId);
    }
  }

  send(method, params = {}, sessionId = undefined) {
    if (this.closed) return Promise.reject(new Error(`${method}: DevTools pipe closed`));
    const id = this.nextId++;
    const msg = { id, method, params };
    if (sessionId) msg.sessionId = sessionId;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject, method });
      this.w.write(JSON.stringify(msg) + '\0');
    });
  }
}

// ---------------------------------------------------------------------------------------------
// Cleanup (also on signals and exceptions)
// ---------------------------------------------------------------------------------------------

const state = { child: null, server: null, profileDir: null, cdp: null };

function killChromium() {
  const c = state.child;
  if (!c) return;
  state.child = null;
  // Chromium was started in its own process group (detached): take the GPU, renderer and zygote
  // processes down with it, also when the browser process itself has already gone.
  try { process.kill(-c.pid, 'SIGKILL'); } catch { /* group empty */ }
  try { c.kill('SIGKILL'); } catch { /* gone */ }
}

function cleanupSync() {
  killChromium();
  if (state.server) {
    try { state.server.closeAllConnections?.(); state.server.close(); } catch { /* closed */ }
    state.server = null;
  }
  if (state.profileDir) {
    try { fs.rmSync(state.profileDir, { recursive: true, force: true, maxRetries: 3 }); } catch { /* best effort */ }
    state.profileDir = null;
  }
}

async function cleanup() {
  const c = state.child;
  if (c && c.exitCode === null && c.signalCode === null) {
    // Ask politely first (Chromium then takes its helper processes down itself, without crash
    // reports), then kill whatever is left.
    const exited = new Promise((r) => c.once('exit', r));
    if (state.cdp && !state.cdp.closed) state.cdp.send('Browser.close').catch(() => {});
    await Promise.race([exited, sleep(1500)]);
  }
  cleanupSync();
}

process.on('exit', cleanupSync);
for (const [sig, code] of [['SIGINT', 130], ['SIGTERM', 143], ['SIGHUP', 129]]) {
  process.on(sig, () => {
    process.stderr.write(`error: interrupted by ${sig}\n`);
    cleanupSync();
    process.exit(code);
  });
}

process.on('uncaughtException', (e) => {
  process.stderr.write(`error: ${String(e && e.message ? e.message : e).split('\n')[0]}\n`);
  cleanupSync();
  process.exit(1);
});

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// ---------------------------------------------------------------------------------------------
// Main
// ---------------------------------------------------------------------------------------------

async function main() {
  let o;
  try {
    o = parseArgs(process.argv.slice(2));
  } catch (e) {
    if (!(e instanceof UsageError)) throw e;
    if (e.message) process.stderr.write(`error: ${e.message}\n`);
    process.stderr.write(USAGE + '\n');
    return 2;
  }
  if (!fs.existsSync(o.dir) || !fs.statSync(o.dir).isDirectory()) throw new Error(`--dir ${o.dir} is not a directory`);

  state.server = await startServer(o.dir);
  const port = state.server.address().port;
  const url = `http://127.0.0.1:${port}/${o.page.replace(/^\/+/, '')}`;

  if (o.verbose) process.stderr.write(`web-driver: serving ${o.dir} as ${url}\n`);
  const exe = findChromium(o.chromium);
  state.profileDir = fs.mkdtempSync(path.join(os.tmpdir(), 'touchfem-chromium-'));
  const args = chromiumArgs(o, state.profileDir);
  if (o.verbose) process.stderr.write(`web-driver: ${exe} ${args.join(' ')}\n`);
  const child = spawn(exe, args, { stdio: ['ignore', 'pipe', 'pipe', 'pipe', 'pipe'], detached: true });
  state.child = child;
  // Keep Chromium's own output (drained, so it never blocks): the tail explains failures.
  let chromeLog = '';
  const keep = (d) => {
    if (o.verbose) process.stderr.write(d);
    chromeLog = (chromeLog + d.toString('utf8')).slice(-8000);
  };
  child.stdout.on('data', keep);
  child.stderr.on('data', keep);
  // Chromium's last line of output that is not about D-Bus (always absent in containers).
  const lastLogLine = () => {
    const line = chromeLog.split('\n').filter((l) => l.trim() && !/dbus/i.test(l)).slice(-1)[0];
    return line ? `: ${line.trim()}` : '';
  };
  let spawnError = null;
  child.on('error', (e) => { spawnError = e; });
  const exitedEarly = new Promise((resolve) => child.once('exit', (code, sig) => resolve({ code, sig })));

  // Page state, filled by events.
  const errors = [];
  const warnings = [];
  let sessionId = null;
  let crashed = null;
  const fmtLoc = (url, line) => (url ? ` (${url}${line !== undefined ? ':' + (line + 1) : ''})` : '');
  const onEvent = (method, p, sid) => {
    if (sessionId && sid && sid !== sessionId) return;
    switch (method) {
      case 'Runtime.consoleAPICalled': {
        if (p.type !== 'error' && p.type !== 'warning' && p.type !== 'assert') return;
        const text = (p.args || []).map(remoteToString).join(' ');
        const top = p.stackTrace?.callFrames?.[0];
        const s = `console.${p.type === 'warning' ? 'warn' : p.type}: ${text}${fmtLoc(top?.url, top?.lineNumber)}`;
        (p.type === 'warning' ? warnings : errors).push(s);
        break;
      }
      case 'Runtime.exceptionThrown': {
        const d = p.exceptionDetails || {};
        const text = d.exception?.description || d.exception?.value || d.text || 'exception';
        errors.push(`uncaught: ${text}${d.exception?.description ? '' : fmtLoc(d.url, d.lineNumber)}`);
        break;
      }
      case 'Log.entryAdded': {
        const e = p.entry || {};
        const s = `${e.source || 'log'}: ${e.text}${fmtLoc(e.url, e.lineNumber)}`;
        if (e.level === 'error') errors.push(s);
        else if (e.level === 'warning') warnings.push(s);
        break;
      }
      case 'Inspector.targetCrashed':
        crashed = 'the page crashed (renderer process died)';
        errors.push(crashed);
        break;
      case 'Target.targetCrashed':
        crashed = `a target crashed (${p.status}, code ${p.errorCode})`;
        errors.push(crashed);
        break;
      default:
    }
  };

  const cdp = new Cdp(child.stdio[3], child.stdio[4], onEvent);
  state.cdp = cdp;
  const tStart = Date.now();
  // First contact: fails fast when Chromium cannot start (missing libraries, sandbox, ...).
  try {
    await Promise.race([
      cdp.send('Browser.getVersion'),
      exitedEarly.then(({ code, sig }) => { throw new Error(`exited (${sig || 'code ' + code})`); }),
      sleep(30000).then(() => { throw new Error('no DevTools answer in 30 s'); }),
    ]);
  } catch (e) {
    // Prefer "exited (code N)" over the pipe error that usually races it.
    const gone = await Promise.race([exitedEarly, sleep(500)]);
    const why = spawnError ? spawnError.message
      : gone ? `${exe} exited (${gone.sig || 'code ' + gone.code})` : e.message;
    throw new Error(`chromium would not start: ${why}${lastLogLine()}`);
  }
  const startupMs = Date.now() - tStart;

  // A page of our own, attached in flat mode (its messages carry our sessionId).
  const { targetId } = await cdp.send('Target.createTarget', { url: 'about:blank' });
  ({ sessionId } = await cdp.send('Target.attachToTarget', { targetId, flatten: true }));
  const S = (method, params) => cdp.send(method, params, sessionId);
  await Promise.all([S('Runtime.enable'), S('Log.enable'), S('Page.enable'), S('Inspector.enable').catch(() => {})]);
  // The viewport is exactly --size at scale 1, whatever the window decorations would take.
  await S('Emulation.setDeviceMetricsOverride', { width: o.width, height: o.height, deviceScaleFactor: 1, mobile: false });

  // A page busy in a long computation (wasm, a hot loop) answers no evaluate until it yields:
  // every call has a time limit, so the driver's own deadline holds.
  const withLimit = (promise, ms, what) => Promise.race([promise,
    sleep(ms).then(() => { throw new Error(`${what}: no answer in ${Math.round(ms)} ms (page busy?)`); })]);
  const evaluate = async (expression, limitMs, awaitPromise = false) => {
    const r = await withLimit(S('Runtime.evaluate', { expression, returnByValue: true, awaitPromise }),
      limitMs, 'Runtime.evaluate');
    if (r.exceptionDetails) throw new Error(`evaluate ${expression}: ${r.exceptionDetails.exception?.description || r.exceptionDetails.text}`);
    return r.result.value;
  };

  const tNav = Date.now();
  const nav = await S('Page.navigate', { url });
  if (nav.errorText) throw new Error(`navigating to ${url}: ${nav.errorText}`);

  // Poll the title. The page tells us it is finished by setting document.title.
  const deadline = T0 + o.timeoutS * 1000;
  let title = '';
  let outcome = 'timeout';
  let failure = null;
  while (Date.now() < deadline) {
    if (crashed) { failure = crashed; outcome = 'failure'; break; }
    try {
      title = (await evaluate('document.title', Math.max(deadline - Date.now(), 50))) ?? '';
    } catch (e) {
      // During navigation the execution context can be replaced under us: try again.
      if (cdp.closed) { failure = `chromium went away${lastLogLine()}`; outcome = 'failure'; break; }
    }
    if (title === 'touchfem:done') { outcome = 'done'; break; }
    if (title.startsWith('touchfem:error:')) { outcome = 'page-error'; break; }
    await sleep(100);
  }
  const pageMs = Date.now() - tNav;

  // Collect what the page left, whatever the outcome (best effort once something failed).
  let result = null;
  let bodyText = '';
  if (outcome !== 'failure') {
    // A finished page answers at once (even tens of MB take a few seconds); a timed-out one may
    // be stuck in a loop: then give up quickly.
    const limit = outcome === 'timeout' ? 3000 : 60000;
    let busy = false;
    try {
      const json = await evaluate('JSON.stringify(window.touchfemResult ?? null)', limit);
      result = json === undefined ? null : JSON.parse(json);
    } catch (e) {
      errors.push(`driver: could not read window.touchfemResult: ${e.message}`);
      busy = /no answer/.test(e.message);
    }
    try {
      if (!busy) bodyText = String((await evaluate('document.body ? document.body.innerText : ""', limit)) ?? '').slice(0, 2000);
    } catch { /* leave empty */ }
    if (o.screenshot && busy) {
      errors.push('driver: no screenshot: the page does not answer');
      if (outcome !== 'timeout') { failure = 'screenshot: the page does not answer'; outcome = 'failure'; }
    } else if (o.screenshot) {
      try {
        // Let one more frame reach the compositor (a canvas shows what was presented before it).
        await evaluate('new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))',
          Math.min(limit, 5000), true).catch(() => {});
        const shot = await withLimit(S('Page.captureScreenshot', { format: 'png' }), limit, 'Page.captureScreenshot');
        fs.writeFileSync(o.screenshot, Buffer.from(shot.data, 'base64'));
      } catch (e) {
        // A missing screenshot fails a finished page; a timed-out one stays a timeout.
        if (outcome === 'timeout') {
          errors.push(`driver: screenshot: ${e.message}`);
        } else {
          failure = `screenshot: ${e.message}`;
          outcome = 'failure';
        }
      }
    }
  }

  const report = { title, result, errors, warnings, body_text: bodyText, elapsed_ms: Date.now() - T0 };
  if (o.verbose) {
    process.stderr.write(`web-driver: chromium answered after ${startupMs} ms, the page took ${pageMs} ms `
      + `from navigation to its title (polled every 100 ms); outcome ${outcome}\n`);
  }
  await cleanup();
  process.stdout.write(JSON.stringify(report) + '\n');
  if (failure) {
    process.stderr.write(`error: ${failure}\n`);
    return 1;
  }
  return { done: 0, 'page-error': 3, timeout: 4 }[outcome];
}

// A console argument (a CDP RemoteObject) as text.
function remoteToString(a) {
  if (!a) return '';
  if (a.type === 'string') return a.value;
  if (a.value !== undefined) return typeof a.value === 'object' ? JSON.stringify(a.value) : String(a.value);
  if (a.unserializableValue !== undefined) return a.unserializableValue;
  // Objects: Chromium sends a shallow preview ({a: 1, b: Array(3)}); errors: their stack.
  const p = a.preview;
  if (p && a.subtype !== 'error' && Array.isArray(p.properties)) {
    const items = p.properties.map((q) => (p.subtype === 'array' ? q.value : `${q.name}: ${q.value}`));
    if (p.overflow) items.push('…');
    return p.subtype === 'array' ? `[${items.join(', ')}]` : `{${items.join(', ')}}`;
  }
  return a.description || a.type;
}

main().then(
  async (code) => {
    await cleanup();
    // Flush stdout before exiting (it can be a pipe holding a large JSON).
    process.stdout.write('', () => process.exit(code));
  },
  async (e) => {
    process.stderr.write(`error: ${String(e && e.message ? e.message : e).split('\n')[0]}\n`);
    await cleanup();
    process.exit(1);
  },
);
