//! End-to-end test of `touchfem view`: the real binary under `Xvfb`, driven by real X pointer
//! events from `xdotool`, captured with `xwd` + ImageMagick's `convert`.
//!
//! Needs the Debian packages `xvfb`, `xdotool`, `x11-apps` (xwd) and `imagemagick`
//! (`scripts/ensure-x11.sh` installs them) and a Vulkan adapter (`scripts/ensure-vulkan.sh`;
//! `WGPU_BACKEND=vulkan` is set for the child unless set already). Missing tools FAIL the test.
//! The captures are saved under `target/view-test/` (`before.png`, `during.png`, the log and
//! the binary's output).

use crate::common;

use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use glam::DVec3;

const SIZE: [u32; 2] = [640, 480];

/// Ends and reaps a child process when dropped (also on a failed assertion): SIGTERM first, so
/// that Xvfb removes its lock file and socket, then SIGKILL after 3 s.
struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            // SAFETY: kill(2) on our own child's pid, which has not been reaped yet.
            unsafe {
                libc::kill(self.0.id() as libc::pid_t, libc::SIGTERM);
            }
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(3) {
                if let Ok(Some(_)) = self.0.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = self.0.kill();
        }
        let _ = self.0.wait();
    }
}

fn out_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .expect("target dir")
        .join("view-test");
    std::fs::create_dir_all(&dir).expect("create target/view-test");
    dir
}

fn on_path(tool: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|p| std::env::split_paths(&p).any(|d| d.join(tool).is_file()))
}

fn require_tools() {
    let missing: Vec<String> = [
        ("Xvfb", "xvfb"),
        ("xdotool", "xdotool"),
        ("xwd", "x11-apps"),
        ("convert", "imagemagick"),
    ]
    .iter()
    .filter(|(tool, _)| !on_path(tool))
    .map(|(tool, pkg)| format!("{tool} (Debian package {pkg})"))
    .collect();
    assert!(
        missing.is_empty(),
        "tests/view.rs needs {}: run scripts/ensure-x11.sh or apt-get install -y xvfb xdotool \
         x11-apps imagemagick",
        missing.join(", ")
    );
}

/// A display number with no server (no socket, no lock file).
fn free_display() -> u32 {
    (90..400)
        .find(|n| {
            !Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()
                && !Path::new(&format!("/tmp/.X{n}-lock")).exists()
        })
        .expect("a free X display number")
}

/// Moves the pointer to (`x`, `y`) in window `win`'s pixels.
fn mouse_to(display: &str, win: &str, x: impl ToString, y: impl ToString) {
    let (x, y) = (x.to_string(), y.to_string());
    xdotool(display, &["mousemove", "--window", win, &x, &y]);
}

fn xdotool(display: &str, args: &[&str]) -> String {
    let out = Command::new("xdotool")
        .args(args)
        .env("DISPLAY", display)
        .output()
        .expect("run xdotool");
    assert!(
        out.status.success(),
        "xdotool {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Captures window `win` to `path` (PNG) and decodes it.
fn capture(display: &str, win: &str, path: &Path) -> image::RgbaImage {
    let xwd = Command::new("xwd")
        .args(["-silent", "-id", win])
        .env("DISPLAY", display)
        .output()
        .expect("run xwd");
    assert!(
        xwd.status.success() && !xwd.stdout.is_empty(),
        "xwd failed: {}",
        String::from_utf8_lossy(&xwd.stderr)
    );
    let mut convert = Command::new("convert")
        .args(["xwd:-", &format!("png:{}", path.display())])
        .stdin(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run convert");
    {
        use std::io::Write as _;
        let mut stdin = convert.stdin.take().unwrap();
        stdin.write_all(&xwd.stdout).expect("pipe to convert");
    }
    let st = convert.wait().expect("convert");
    assert!(st.success(), "convert xwd:- png failed");
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgba8()
}

fn differs(a: &image::Rgba<u8>, b: &image::Rgba<u8>, by: i32) -> bool {
    (0..3).any(|c| (i32::from(a[c]) - i32::from(b[c])).abs() > by)
}

/// Fraction of pixels in `[x0, x1) × [y0, y1)` where `a` and `b` differ by more than `by`.
fn changed(a: &image::RgbaImage, b: &image::RgbaImage, r: [u32; 4], by: i32) -> f64 {
    let [x0, y0, x1, y1] = r;
    let mut n = 0;
    for y in y0..y1 {
        for x in x0..x1 {
            n += usize::from(differs(a.get_pixel(x, y), b.get_pixel(x, y), by));
        }
    }
    n as f64 / f64::from((x1 - x0) * (y1 - y0))
}

fn read_log(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// Starts Xvfb on a free display; returns it (ended when dropped) and the display's name.
fn start_xvfb() -> (KillOnDrop, String) {
    let n = free_display();
    let display = format!(":{n}");
    let xvfb = Command::new("Xvfb")
        .args([&display, "-screen", "0", "1024x768x24", "-nolisten", "tcp"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start Xvfb");
    let mut xvfb = KillOnDrop(xvfb);
    let socket = PathBuf::from(format!("/tmp/.X11-unix/X{n}"));
    wait_until(
        "Xvfb's socket",
        Duration::from_secs(15),
        &mut xvfb.0,
        || socket.exists(),
    );
    (xvfb, display)
}

/// Focuses `win` and presses Esc (keys go to the focused window; there is no window manager
/// to focus it), waits up to `timeout` for `view` to quit, and asserts that it succeeded.
fn quit_on_escape(display: &str, win: &str, xvfb: &mut Child, view: &mut Child, timeout: Duration) {
    xdotool(display, &["windowfocus", "--sync", win]);
    xdotool(display, &["key", "Escape"]);
    wait_until("touchfem view to quit on Esc", timeout, xvfb, || {
        matches!(view.try_wait(), Ok(Some(_)))
    });
    let status = view.wait().unwrap();
    assert!(status.success(), "touchfem view exited with {status}");
}

fn wait_until(what: &str, timeout: Duration, child: &mut Child, mut ok: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ok() {
        if let Ok(Some(st)) = child.try_wait() {
            panic!("touchfem view exited ({st}) while waiting for {what}; see target/view-test/");
        }
        assert!(t0.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Starts `touchfem view SCENE` on `display` recording to `session` and logging to `log` (its
/// stderr in `dir`), for at most `seconds`; waits for its window and its first log line.
/// Returns the process and the window's id.
fn start_view(
    scene: &str,
    dir: &Path,
    display: &str,
    session: &Path,
    log: &Path,
    stdout: std::fs::File,
    seconds: u64,
) -> (KillOnDrop, String) {
    let stderr = std::fs::File::create(dir.join("view.stderr.txt")).unwrap();
    let backend = std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "vulkan".into());
    let child = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args([
            "view",
            scene,
            "--size",
            &format!("{}x{}", SIZE[0], SIZE[1]),
            "--record",
            session.to_str().unwrap(),
        ])
        .env("DISPLAY", display)
        .env("WGPU_BACKEND", backend)
        .env("TOUCHFEM_VIEW_SECONDS", seconds.to_string())
        .env("TOUCHFEM_VIEW_LOG", log)
        .env("TOUCHFEM_CACHE_DIR", "")
        .stdout(stdout)
        .stderr(stderr)
        .spawn()
        .expect("start touchfem view");
    let mut view = KillOnDrop(child);
    // The window, and a first log line (the window has presented frames for a second).
    let mut search = Command::new("xdotool")
        .args(["search", "--sync", "--name", "touchfem"])
        .env("DISPLAY", display)
        .stdout(Stdio::piped())
        .spawn()
        .expect("xdotool search");
    let t0 = Instant::now();
    let found = loop {
        if let Some(st) = search.try_wait().unwrap() {
            break st.success();
        }
        if let Ok(Some(st)) = view.0.try_wait() {
            let _ = search.kill();
            let err = std::fs::read_to_string(dir.join("view.stderr.txt")).unwrap_or_default();
            panic!("touchfem view exited ({st}) before its window appeared:\n{err}");
        }
        if t0.elapsed() > Duration::from_secs(seconds) {
            let _ = search.kill();
            panic!("no window named touchfem after {seconds} s");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(found, "xdotool search failed");
    let mut ids = String::new();
    search
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut ids)
        .unwrap();
    let win = ids.lines().next().expect("a window id").trim().to_string();
    wait_until(
        "the first log line",
        Duration::from_secs(30),
        &mut view.0,
        || !read_log(log).is_empty(),
    );
    (view, win)
}

#[test]
fn view_window_presses_the_cube_with_the_pointer() {
    require_tools();
    let dir = out_dir();
    let (mut xvfb, display) = start_xvfb();

    let log = dir.join("view.log.jsonl");
    let _ = std::fs::remove_file(&log);
    let session = dir.join("view.tfsession");
    let _ = std::fs::remove_file(&session);
    let stdout = std::fs::File::create(dir.join("view.stdout.txt")).unwrap();
    let (mut view, win) = start_view("cube", &dir, &display, &session, &log, stdout, 60);

    let before = capture(&display, &win, &dir.join("before.png"));
    assert_eq!(before.dimensions(), (SIZE[0], SIZE[1]), "window size");

    // The object is there: the background is the bottom-right corner's colour.
    let bg = *before.get_pixel(SIZE[0] - 2, SIZE[1] - 2);
    let object = before.pixels().filter(|p| differs(p, &bg, 12)).count() as f64
        / f64::from(SIZE[0] * SIZE[1]);
    eprintln!(
        "before: {:.1} % of the pixels are not background",
        100.0 * object
    );
    assert!(
        object > 0.15,
        "only {:.1} % of the window shows the cube",
        100.0 * object
    );

    // Press the middle of the top face (as the window frames the cube) and drag 120 px down.
    let (lo, hi) = (DVec3::ZERO, DVec3::splat(0.03));
    let camera =
        touchfem::render::Orbit::framing(lo, hi, f64::from(SIZE[0]) / f64::from(SIZE[1])).camera();
    let [px, py] = camera
        .project(DVec3::new(0.015, 0.015, 0.03), SIZE)
        .expect("the top face is in view");
    let (px, py) = (px.round() as u32, py.round() as u32);
    mouse_to(&display, &win, px, py);
    std::thread::sleep(Duration::from_millis(200));
    xdotool(&display, &["mousedown", "1"]);
    for step in 1..=6 {
        std::thread::sleep(Duration::from_millis(100));
        mouse_to(&display, &win, px, py + 20 * step);
    }
    std::thread::sleep(Duration::from_millis(1500));
    let during = capture(&display, &win, &dir.join("during.png"));
    xdotool(&display, &["mouseup", "1"]);

    // Near the press the picture changed; the far corners did not.
    let near = [px - 70, py - 50, px + 70, py + 130];
    let near_changed = changed(&before, &during, near, 24);
    eprintln!(
        "pressed at ({px}, {py}): {:.1} % of the pixels around it changed",
        100.0 * near_changed
    );
    assert!(
        near_changed > 0.10,
        "only {:.1} % of the pixels around the press changed",
        100.0 * near_changed
    );
    let (w, h) = (SIZE[0], SIZE[1]);
    for (name, r) in [
        ("top right", [w - 60, 0, w, 60]),
        ("bottom left", [0, h - 60, 60, h]),
        ("bottom right", [w - 60, h - 60, w, h]),
    ] {
        let c = changed(&before, &during, r, 2);
        assert!(c == 0.0, "the {name} corner changed ({:.1} %)", 100.0 * c);
    }

    // Esc quits (keys go to the focused window; there is no window manager to focus it);
    // then the log has a summary.
    quit_on_escape(
        &display,
        &win,
        &mut xvfb.0,
        &mut view.0,
        Duration::from_secs(20),
    );
    let lines = read_log(&log);
    let max_force = lines
        .iter()
        .filter_map(|l| l["force_n"].as_f64().or(l["max_force_n"].as_f64()))
        .fold(0.0, f64::max);
    let summary = lines
        .iter()
        .find(|l| l["summary"] == true)
        .expect("a summary line");
    let haptic = summary["haptic_hz"].as_f64().unwrap();
    eprintln!(
        "log: max |F| {max_force:.3} N, haptic {haptic:.0} Hz, median frame {:.2} ms",
        summary["frame_ms_median"].as_f64().unwrap()
    );
    assert!(max_force > 0.05, "the drag pressed with only {max_force} N");
    assert!(haptic > 500.0, "haptic rate {haptic} Hz");
    // Every per-second line counts the haptic loop's missed deadlines so far: never fewer
    // than the line before, and (at 1 kHz, a few seconds) never more than the ticks.
    let missed: Vec<u64> = lines
        .iter()
        .filter(|l| l["summary"] != true)
        .map(|l| l["haptic_missed"].as_u64().expect("haptic_missed"))
        .collect();
    assert!(!missed.is_empty());
    assert!(missed.windows(2).all(|w| w[0] <= w[1]), "{missed:?}");
    let ticks = 1000.0 * summary["seconds"].as_f64().expect("the run's seconds");
    assert!((*missed.last().unwrap() as f64) < ticks, "{missed:?}");

    // The session it recorded (the pointer's positions and the forces sent, every tick)
    // replays through the haptic path to exactly the same forces.
    let r = common::replay_json(&session);
    eprintln!("replay: {r}");
    assert!(r["ticks"].as_u64().unwrap() > 1000, "{r}");
    assert_eq!(r["max_force_diff_n"].as_f64(), Some(0.0), "{r}");
    assert!(r["max_force_n"].as_f64().unwrap() > 0.05, "{r}");
}

/// `Renderer::render_frame` draws several objects, each at its offset, with 1 and 4 samples;
/// with one object it is `render_with`'s image, bit for bit. Needs a GPU adapter (no X).
#[test]
fn render_frame_draws_objects_at_their_offsets() {
    use touchfem::compliance::{Compliance, Selection};
    use touchfem::gpu::{Deformer, DeformerOptions, Gpu};
    use touchfem::render::{FrameObject, Picture, RenderOptions, Renderer, COLOR_FORMAT};
    let gpu = Gpu::new_headless().expect("a GPU adapter (WGPU_BACKEND=vulkan with lavapipe)");
    let mesh = touchfem::mesh::cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let d = Deformer::new(
        &gpu.device,
        &gpu.queue,
        &c,
        &mesh.nodes,
        &mesh.surface,
        &DeformerOptions::default(),
    )
    .unwrap();
    let size = [400, 200];
    let one = [FrameObject {
        deformer: &d,
        offset: DVec3::ZERO,
        bounds: mesh.bounds(),
        edges: None,
        deformed: false,
    }];
    let r4 = Renderer::new(&gpu.device, size).unwrap();
    let a = r4
        .render_frame(&gpu.device, &gpu.queue, &one, &[], &[], true)
        .unwrap();
    let scene = Picture {
        wireframe: true,
        ..Picture::at_rest(&mesh, &c)
    };
    let b = r4.render_with(&gpu.device, &gpu.queue, &d, &scene).unwrap();
    assert!(
        a == b,
        "render_frame of one object differs from render_with"
    );

    let two = [
        one[0],
        FrameObject {
            offset: DVec3::new(0.06, 0.0, 0.0),
            ..one[0]
        },
    ];
    for samples in [1, 4] {
        let r = Renderer::with_options(
            &gpu.device,
            size,
            RenderOptions {
                samples,
                format: COLOR_FORMAT,
            },
        )
        .unwrap();
        let img = r
            .render_frame(&gpu.device, &gpu.queue, &two, &[], &[], false)
            .unwrap();
        img.save(out_dir().join(format!("two_cubes_{samples}.png")))
            .unwrap();
        let bg = *img.get_pixel(0, 0);
        // Two objects side by side: the columns that show something form two runs, each a
        // good part of the image.
        let shows = |x: u32| (0..size[1]).any(|y| differs(img.get_pixel(x, y), &bg, 12));
        let mut runs = Vec::new();
        let mut start = None;
        for x in 0..=size[0] {
            match (x < size[0] && shows(x), start) {
                (true, None) => start = Some(x),
                (false, Some(s)) => {
                    runs.push((s, x));
                    start = None;
                }
                _ => {}
            }
        }
        eprintln!("{samples} samples: object columns {runs:?}");
        assert_eq!(runs.len(), 2, "{samples} samples: object columns {runs:?}");
        assert!(runs.iter().all(|(a, b)| b - a > size[0] / 8), "{runs:?}");
    }
}

/// `touchfem serve cube --udp … --view`: the window shows what a UDP client presses. Under
/// Xvfb: a client presses the top face 5 mm over loopback; the window's picture changes around
/// the top while the corners do not, the client feels the force, and Ctrl-C (SIGINT) ends the
/// run with a report (no packet lost).
#[test]
fn serve_view_shows_a_udp_press_in_the_window() {
    use touchfem::devices::udp::{decode_force, encode_position};
    require_tools();
    let dir = out_dir();
    let (mut xvfb, display) = start_xvfb();
    let report = dir.join("serve-view.json");
    let _ = std::fs::remove_file(&report);
    let stderr_path = dir.join("serve-view.stderr.txt");
    let backend = std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "vulkan".into());
    let child = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args([
            "serve",
            "cube",
            "--udp",
            "127.0.0.1:0",
            "--view",
            "--size",
            &format!("{}x{}", SIZE[0], SIZE[1]),
            "--report",
            report.to_str().unwrap(),
        ])
        .env("DISPLAY", &display)
        .env("WGPU_BACKEND", backend)
        .env("TOUCHFEM_CACHE_DIR", "")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&stderr_path).unwrap())
        .spawn()
        .expect("start touchfem serve --view");
    let mut serve = KillOnDrop(child);
    let mut addr = None;
    wait_until(
        "serve's address",
        Duration::from_secs(60),
        &mut serve.0,
        || {
            let err = std::fs::read_to_string(&stderr_path).unwrap_or_default();
            addr = err
                .lines()
                .find_map(|l| l.strip_prefix("listening on udp "))
                .and_then(|a| a.trim().parse::<std::net::SocketAddr>().ok());
            addr.is_some()
        },
    );
    let addr = addr.unwrap();
    let win = loop {
        let out = Command::new("xdotool")
            .args(["search", "--name", "touchfem serve"])
            .env("DISPLAY", &display)
            .output()
            .expect("xdotool search");
        if let Some(w) = String::from_utf8_lossy(&out.stdout).lines().next() {
            break w.trim().to_string();
        }
        wait_until("the window", Duration::from_secs(60), &mut serve.0, || {
            std::thread::sleep(Duration::from_millis(200));
            true
        });
    };
    std::thread::sleep(Duration::from_millis(1500));
    let before = capture(&display, &win, &dir.join("serve-before.png"));

    // The client: from 6 mm above the top face's centre to 5 mm into it over 0.3 s, held.
    let client = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    client.set_nonblocking(true).unwrap();
    let mm = 1e-3;
    let mut force: f64 = 0.0;
    let (mut buf, mut inp) = ([0u8; 64], [0u8; 256]);
    let t0 = Instant::now();
    let mut during = None;
    let mut seq = 0u32;
    while t0.elapsed() < Duration::from_secs(4) {
        let s = (t0.elapsed().as_secs_f64() / 0.3).min(1.0);
        let p = DVec3::new(15.0, 15.0, 36.0 - 11.0 * s) * mm;
        seq += 1;
        let len = encode_position(seq, &[p], &mut buf);
        client.send_to(&buf[..len], addr).unwrap();
        while let Ok((len, _)) = client.recv_from(&mut inp) {
            if let Some(f) = decode_force(&inp[..len]) {
                force = force.max(f.forces[0].length());
            }
        }
        if during.is_none() && t0.elapsed() > Duration::from_secs(2) {
            during = Some(capture(&display, &win, &dir.join("serve-during.png")));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let during = during.unwrap();
    let (lo, hi) = (DVec3::ZERO, DVec3::splat(0.03));
    let camera =
        touchfem::render::Orbit::framing(lo, hi, f64::from(SIZE[0]) / f64::from(SIZE[1])).camera();
    let [px, py] = camera
        .project(DVec3::new(0.015, 0.015, 0.03), SIZE)
        .expect("the top face is in view");
    let (px, py) = (px.round() as u32, py.round() as u32);
    let near = changed(
        &before,
        &during,
        [
            px.saturating_sub(70),
            py.saturating_sub(90),
            px + 70,
            py + 90,
        ],
        24,
    );
    let (w, h) = (SIZE[0], SIZE[1]);
    let corner = changed(&before, &during, [0, h - 60, 60, h], 2)
        + changed(&before, &during, [w - 60, h - 60, w, h], 2);
    eprintln!(
        "serve --view: {:.1} % changed around the press, max |F| {force:.3} N",
        100.0 * near
    );
    assert!(
        near > 0.05,
        "only {:.1} % changed around the press",
        100.0 * near
    );
    assert_eq!(corner, 0.0, "a corner changed");
    assert!(force > 0.05, "the client felt {force} N");

    // Ctrl-C ends the run: the window closes and the report is written.
    // SAFETY: kill(2) on our own child's pid, which has not been reaped yet.
    unsafe {
        libc::kill(serve.0.id() as libc::pid_t, libc::SIGINT);
    }
    wait_until(
        "serve to end on SIGINT",
        Duration::from_secs(20),
        &mut xvfb.0,
        || matches!(serve.0.try_wait(), Ok(Some(_))),
    );
    let status = serve.0.wait().unwrap();
    assert!(status.success(), "serve --view exited with {status}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    eprintln!(
        "report: ticks {}, packets {}",
        r["ticks"], r["packets_received"]
    );
    assert!(r["packets_received"].as_u64().unwrap() > 1000, "{r}");
    assert_eq!(r["packets_dropped"].as_u64(), Some(0), "{r}");
    assert!(r["max_force_n"].as_f64().unwrap() > 0.05, "{r}");
}

/// The phantom with a cuttable ball under its top face and only the window's pointer: `view`
/// gives the pointer a blade twin of the default depth (5 mm: a quarter of the 20 mm height).
const CUTTABLE_PHANTOM: &str = r#"
unit = "mm"

[[object]]
name = "tissue"
mesh = "phantom"
young = 3000.0
poisson = 0.45
touchable = "top"
cuttable = { center = [-15.0, 0.0, 16.0], radius = 14.0 }

[[finger]]
device = "pointer"
"#;

/// What one pointer stroke across the phantom's cuttable ball did, through the real haptic
/// loop ([`run_haptic`](touchfem::runtime::run_haptic), which starts the cutter's thread) and
/// the devices `view` gives the scene's fingers.
struct Stroke {
    /// Tets the cutter removed (its own count, and the visual feed's).
    tets_removed: usize,
    feed_tets: usize,
    /// Copies of nodes the cutter made (its own count, and the visual feed's).
    nodes_split: usize,
    feed_split: usize,
    /// The largest force sent to the finger the pointer drove, and to any finger, N.
    pointer_force_n: f64,
    max_force_n: f64,
    ticks: u64,
}

/// Drives `route` as the window does in the mode it is in: the finger put 0.5 mm under the top
/// face (z = 20 mm) at x = −25 mm, y = 0 and drawn 20 mm along x over about a second, then
/// lifted.
fn pointer_stroke(
    w: &touchfem::scene::World,
    route: &touchfem_app::window::PointerRoute,
) -> Stroke {
    use std::sync::atomic::Ordering;
    use touchfem::runtime::{run_haptic, sample_channel, LiveStatus};
    let mut devs = touchfem_app::window::cli::view_devices(w, route).unwrap();
    let (mut writer, _reader) = sample_channel();
    let status = LiveStatus::default();
    let mm = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) * 1e-3;
    let (run, pointer_force_n) = std::thread::scope(|s| {
        let haptic = s.spawn(|| run_haptic(w, &mut devs, None, &mut writer, &status, None));
        let t0 = Instant::now();
        while status.ticks.load(Ordering::Relaxed) < 50 {
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "the haptic loop ticks"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        let mut force: f64 = 0.0;
        let steps = 1000;
        for k in 0..=steps {
            let x = -25.0 + 20.0 * k as f64 / steps as f64;
            route.set_position(mm(x, 0.0, 19.5));
            std::thread::sleep(Duration::from_millis(1));
            force = force.max(route.force().length());
        }
        route.lift();
        std::thread::sleep(Duration::from_millis(100));
        status.stop.store(true, Ordering::SeqCst);
        (haptic.join().unwrap(), force)
    });
    Stroke {
        tets_removed: run.cuts.tets_removed,
        feed_tets: status
            .cuts
            .latest()
            .iter()
            .map(|(_, b)| b.tets_removed)
            .sum(),
        nodes_split: run.cuts.nodes_split,
        feed_split: status
            .cuts
            .latest()
            .iter()
            .map(|(_, b)| b.nodes_split)
            .sum(),
        pointer_force_n,
        max_force_n: run.stats.max_force_n,
        ticks: status.ticks.load(std::sync::atomic::Ordering::Relaxed),
    }
}

/// `B` in `view` (the haptic side, no window): a scene with a cuttable object gets the
/// pointer's blade twin in its text (default depth 5 mm here; the scene's own blade depth in
/// `incision`), the cutter's thread starts, and the same pointer stroke across the cuttable
/// ball parts it with blade mode on (copies of nodes, at zero force) and cuts nothing with it
/// off (the point presses); a scene with nothing cuttable gets no twin, and `B` says why and changes nothing.
#[test]
fn view_blade_mode_cuts_only_while_it_is_on() {
    use touchfem::scene::{DeviceSpec, SceneSource, World};
    use touchfem_app::window::blade::{blade_twin, DEFAULT_BLADE_M};
    use touchfem_app::window::cli::load_with_pointer;
    use touchfem_app::window::PointerRoute;

    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("cut_me.toml");
    std::fs::write(&scene, CUTTABLE_PHANTOM).unwrap();
    let w = load_with_pointer(scene.to_str().unwrap(), None).unwrap();
    assert_eq!(w.fingers.len(), 2, "the pointer and its blade twin");
    let twin = blade_twin(&w).unwrap();
    assert_eq!((twin.pointer, twin.finger), (0, 1));
    assert_eq!(twin.depth_m, DEFAULT_BLADE_M);
    assert!(matches!(w.fingers[1].device, DeviceSpec::Pointer));
    assert!(w.source.contains("tool = { blade = 5.0 }"), "{}", w.source);
    // The twin is in the text: a session's scene loads with the same fingers.
    let again = World::from_source_with(
        &SceneSource {
            name: w.name.clone(),
            text: w.source.clone(),
            dir: w.dir.clone(),
            label: "cut_me".into(),
        },
        None,
    )
    .unwrap();
    assert_eq!(again.fingers, w.fingers);
    assert!(w.objects[0].body.compliance.holds_l(), "the cutter needs L");

    let off = pointer_stroke(&w, &PointerRoute::new(&w));
    let mut route = PointerRoute::new(&w);
    assert_eq!(route.toggle_blade(), Ok(true));
    assert_eq!(route.blade_depth_m(), Some(DEFAULT_BLADE_M));
    let on = pointer_stroke(&w, &route);
    eprintln!(
        "blade off: {} tets removed, {} copies, pointer |F| {:.3} N, {} ticks; blade on: {} copies \
         ({} in the feed), {} tets dropped ({} in the feed), pointer |F| {:.3} N, max |F| {:.3} N, \
         {} ticks",
        off.tets_removed,
        off.nodes_split,
        off.pointer_force_n,
        off.ticks,
        on.nodes_split,
        on.feed_split,
        on.tets_removed,
        on.feed_tets,
        on.pointer_force_n,
        on.max_force_n,
        on.ticks
    );
    assert_eq!((off.tets_removed, off.nodes_split), (0, 0));
    assert_eq!((off.feed_tets, off.feed_split), (0, 0));
    assert!(
        off.pointer_force_n > 1e-3,
        "the point presses: {}",
        off.pointer_force_n
    );
    // The default blade separates: copies, and no tets dropped but slivers.
    assert!(on.nodes_split > 0, "the blade parted nothing");
    assert!(on.tets_removed <= 3 * on.nodes_split, "{}", on.tets_removed);
    assert_eq!(on.feed_split, on.nodes_split);
    assert_eq!(on.feed_tets, on.tets_removed);
    assert_eq!(on.pointer_force_n, 0.0, "a blade presses nothing");
    assert_eq!(on.max_force_n, 0.0);
    // Off again: the scene's tool, and the blade lifted.
    assert_eq!(route.toggle_blade(), Ok(false));
    assert_eq!(route.blade_depth_m(), None);
    assert!(route.twin().unwrap().0.position().is_nan());

    // Nothing cuttable: no twin, and `B` changes nothing.
    let cube = load_with_pointer("cube", None).unwrap();
    assert_eq!(cube.fingers.len(), 1);
    let mut route = PointerRoute::new(&cube);
    let why = route.toggle_blade().unwrap_err();
    assert!(why.contains("cuttable"), "{why}");
    assert!(!route.blade_on());

    // The incision: its scripted blade's depth (8 mm) for the twin of the added pointer.
    let inc = load_with_pointer("incision", None).unwrap();
    assert_eq!(inc.fingers.len(), 4);
    let twin = blade_twin(&inc).unwrap();
    assert_eq!((twin.pointer, twin.finger), (2, 3));
    assert!((twin.depth_m - 8e-3).abs() < 1e-15, "{}", twin.depth_m);
}

/// `B` in the real window (under Xvfb, real X events): on the phantom with a cuttable ball, a
/// drag across the ball cuts nothing with the scene's point, and the same drag after `B` cuts
/// (the window's log counts the copies the blade made; the summary line says `cut T tets, N
/// copies`); the
/// recorded session, whose text carries the blade twin, replays to the same forces.
#[test]
fn view_window_b_turns_the_pointer_into_a_blade() {
    require_tools();
    let dir = out_dir().join("blade");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("cut_me.toml");
    std::fs::write(&scene, CUTTABLE_PHANTOM).unwrap();
    let (mut xvfb, display) = start_xvfb();
    let log = dir.join("view.log.jsonl");
    let _ = std::fs::remove_file(&log);
    let session = dir.join("view.tfsession");
    let _ = std::fs::remove_file(&session);
    let stdout_path = dir.join("view.stdout.txt");
    let stdout = std::fs::File::create(&stdout_path).unwrap();
    let (mut view, win) = start_view(
        scene.to_str().unwrap(),
        &dir,
        &display,
        &session,
        &log,
        stdout,
        90,
    );

    // Where the window's camera shows the line x = −25 … −5 mm, y = 0 on the top face.
    let (lo, hi) = touchfem::mesh::phantom().bounds();
    assert!(
        ((hi - lo).x - 0.06).abs() < 1e-3,
        "the phantom, 60 mm long: {lo} {hi}"
    );
    let camera =
        touchfem::render::Orbit::framing(lo, hi, f64::from(SIZE[0]) / f64::from(SIZE[1])).camera();
    let at = |x_mm: f64| {
        let [px, py] = camera
            .project(DVec3::new(x_mm * 1e-3, 0.0, hi.z), SIZE)
            .expect("the top face is in view");
        (px.round() as i64, py.round() as i64)
    };
    let drag = || {
        let (x, y) = at(-25.0);
        mouse_to(&display, &win, x, y);
        std::thread::sleep(Duration::from_millis(200));
        xdotool(&display, &["mousedown", "1"]);
        for step in 1..=20 {
            std::thread::sleep(Duration::from_millis(60));
            let (x, y) = at(-25.0 + f64::from(step));
            mouse_to(&display, &win, x, y);
        }
        std::thread::sleep(Duration::from_millis(300));
        xdotool(&display, &["mouseup", "1"]);
    };
    let most = |lines: &[serde_json::Value], key: &str| {
        lines
            .iter()
            .filter_map(|l| l[key].as_u64())
            .max()
            .unwrap_or(0)
    };
    let tets = |lines: &[serde_json::Value]| most(lines, "tets_removed");
    let copies = |lines: &[serde_json::Value]| most(lines, "nodes_split");

    // The scene's point: a press, no cut.
    drag();
    let n = read_log(&log).len();
    wait_until(
        "two more log lines",
        Duration::from_secs(20),
        &mut view.0,
        || read_log(&log).len() >= n + 2,
    );
    let lines = read_log(&log);
    assert_eq!((tets(&lines), copies(&lines)), (0, 0), "the point cut");
    assert!(lines.iter().all(|l| l["blade"] == false));
    let pressed = lines
        .iter()
        .filter_map(|l| l["force_n"].as_f64())
        .fold(0.0, f64::max);
    assert!(pressed > 0.01, "the point pressed with {pressed} N");

    // `B`, the same drag: the blade cuts.
    xdotool(&display, &["windowfocus", "--sync", &win]);
    xdotool(&display, &["key", "b"]);
    std::thread::sleep(Duration::from_millis(300));
    drag();
    wait_until(
        "a log line with copies made",
        Duration::from_secs(30),
        &mut view.0,
        || copies(&read_log(&log)) > 0,
    );
    let lines = read_log(&log);
    assert_eq!(lines.last().unwrap()["blade"], true);
    let (split, removed) = (copies(&lines), tets(&lines));
    let _ = capture(&display, &win, &dir.join("cut.png"));

    quit_on_escape(
        &display,
        &win,
        &mut xvfb.0,
        &mut view.0,
        Duration::from_secs(30),
    );
    let out = std::fs::read_to_string(&stdout_path).unwrap();
    eprintln!("{out}log: {split} copies, {removed} tets dropped, the point pressed {pressed:.3} N");
    // "…, cut T tets, N copies": the default blade separates; no tets dropped but slivers.
    let summary = out
        .split("cut ")
        .nth(1)
        .unwrap_or_else(|| panic!("no `cut T tets, N copies` in: {out}"));
    let number = |after: &str| -> u64 {
        let words: Vec<&str> = summary
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|w| !w.is_empty())
            .collect();
        let i = words.iter().position(|w| *w == after).expect(after);
        words[i - 1].parse().unwrap()
    };
    let (cut_tets, cut_copies) = (number("tets"), number("copies"));
    assert!(cut_copies >= split && split > 0, "{cut_copies} vs {split}");
    assert!(
        cut_tets >= removed && cut_tets <= 3 * cut_copies,
        "{cut_tets} vs {removed}"
    );

    let r = common::replay_json(&session);
    eprintln!("replay: {r}");
    assert_eq!(r["max_force_diff_n"].as_f64(), Some(0.0), "{r}");
}

/// The closest point of triangle `abc` to `p` (Ericson, *Real-Time Collision Detection*,
/// 5.1.5): an independent check of where the dragged blade sits, not the engine's contact code.
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// A blade (`B`) dragged across the mouse's curved back stays its sink under the surface under
/// the cursor, as the issue asks ("follows the surface"), where the plane tangent at the press,
/// which the drag used before, leaves the body by millimetres.
#[test]
fn a_dragged_blade_follows_the_mouses_curved_surface() {
    use touchfem::contact::Surface;
    use touchfem::render::{pick, Camera, PointerPress, ViewScales};
    let mesh = touchfem::mesh::mouse();
    let surface = Surface::new(&mesh);
    let (lo, hi) = mesh.bounds();
    let size = [640u32, 480];
    let camera = Camera::framing(lo, hi, 640.0 / 480.0);
    let objects = [(&surface, DVec3::ZERO)];
    let sink = 0.5e-3;
    let scales = ViewScales {
        diag: (hi - lo).length(),
        color_scale: (1e-3, 1e-4),
        arrow_m_per_n: 1e-3,
        depth_per_px: 1e-4,
        blade_sink_m: sink,
    };
    let start = [320.0, 240.0];
    let h = pick(&camera, size, start, &objects).expect("the view's centre is on the mouse");
    let press = PointerPress {
        pixel: start,
        point: h.point,
        normal: h.normal,
        object: h.object,
    };
    // The distance of a point to the rest surface, by brute force over its triangles.
    let to_surface = |x: DVec3| {
        surface
            .tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| surface.nodes[i as usize]);
                (closest_on_triangle(x, a, b, c) - x).length()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let (mut on, mut worst_follow, mut worst_plane) = (0, 0.0f64, 0.0f64);
    for k in -12..=12 {
        for cursor in [
            [start[0] + 15.0 * k as f64, start[1]],
            [start[0], start[1] + 10.0 * k as f64],
        ] {
            let Some(hit) = pick(&camera, size, cursor, &objects) else {
                continue;
            };
            on += 1;
            let x = press
                .drag(&camera, size, cursor, true, &scales, &objects)
                .expect("on the mouse, the blade has a place");
            // Under the surface point under the cursor, by the sink, along its normal.
            assert!((x - (hit.point - hit.normal * sink)).length() < 1e-12);
            worst_follow = worst_follow.max((to_surface(x) - sink).abs());
            // The tangent plane at the press, as the drag was before.
            let (eye, dir) = camera.ray(cursor, size);
            let t = (press.point - eye).dot(press.normal) / dir.dot(press.normal);
            let plane = eye + dir * t - press.normal * sink;
            worst_plane = worst_plane.max(to_surface(plane));
        }
    }
    eprintln!(
        "{on} cursor places on the mouse: the blade within {worst_follow:.2e} m of its sink \
         ({sink} m) under the surface; the tangent plane up to {worst_plane:.2e} m off it"
    );
    assert!(on >= 20, "{on}");
    // Within 5 % of the sink (1 % measured: near an edge another facet can be nearer).
    assert!(worst_follow <= 0.05 * sink, "{worst_follow}");
    assert!(
        worst_plane > 5.0 * sink,
        "the old drag drifts: {worst_plane}"
    );
    // Off the mouse the blade still slides in the tangent plane.
    let off = press.drag(&camera, size, [2.0, 2.0], true, &scales, &objects);
    assert!(off.is_none_or(|x| x.is_finite()));
}
