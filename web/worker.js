// touchfem's compliance worker: computes a scene's `L` off the page's thread (the engine,
// compiled to wasm, on this worker's one thread) and hands it back as a cache file's bytes,
// which the page then reads as it reads a served cache file. No physics here.
import init, { compute_cache } from './touchfem_web.js';

self.onmessage = async (e) => {
  try {
    await init();
    const t0 = performance.now();
    const bytes = compute_cache(e.data.scene);
    const ms = performance.now() - t0;
    if (bytes === undefined) {
      self.postMessage({ ok: true, bytes: null, ms });
    } else {
      self.postMessage({ ok: true, bytes, ms }, [bytes.buffer]);
    }
  } catch (err) {
    self.postMessage({ ok: false, error: String(err && err.message ? err.message : err) });
  }
};
