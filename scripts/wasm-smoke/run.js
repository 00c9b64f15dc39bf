// Runs the wasm-smoke module (no imports: the pure engine) and checks its numbers against the
// native engine's (crates/core/src/haptic/pure_tests.rs). Usage: node run.js module.wasm
const fs = require('fs');
const m = new WebAssembly.Module(fs.readFileSync(process.argv[2]));
const imports = WebAssembly.Module.imports(m);
if (imports.length) throw new Error('the module imports ' + JSON.stringify(imports));
const x = new WebAssembly.Instance(m, {}).exports;
const force = x.press_force_z(); // traps (throws) if the engine panics
const dense = x.cube_trace();
const hier = x.cube_hier_trace();
console.log(`press force ${force} N, cube trace ${dense} (dense), ${hier} (hierarchical)`);
const native = 0.6756209949956736; // FORCE[2] of pure_tests.rs
if (!(Math.abs(force - native) <= 1e-12 * native)) throw new Error(`force ${force} != ${native}`);
if (!(dense > 0 && Math.abs(hier - dense) <= 1e-6 * dense)) throw new Error('traces differ');
console.log('the pure engine runs on wasm32 and gives the native numbers');
