// Held-frame stages of the viewer on the peers harness scene (not a test; web/docs/viewer.md "Viewer speed against
// the peers"): held frames (sort reused) at the harness reference pose, at 800x450 and 80x45 (fill / 100),
// Rgba16Float vs 8-bit accumulation, and blank (no splat). The PLY: copy ../shared/peers-bench scene_100k.ply to
// tests/artifacts/bench/peers_100k.ply. Usage (one bundle per process; alternate bundles for a before/after):
//   VIEWER_PKG=DIR NODE_PATH=package-config/node_modules node tests/browser/lib/peers-scene-stages.mjs 100k 2 1 f16@800,u8@800,f16@80
import { startServer, launch, openHarness } from "./viewer-harness.mjs";
const n = process.argv[2] || "100k";
const frames = Number(process.argv[3] || 2);
const rounds = Number(process.argv[4] || 2);
const configs = (process.argv[5] || "f16@800,u8@800,f16@80,blank@800").split(",");
const server = await startServer();
const b = await launch("webgl2");
function cam(W, H) {
  const f = (H / 2) / Math.tan(Math.PI / 6), a = -12 * Math.PI / 180;
  const c = Math.cos(a), s = Math.sin(a), x = -25 * s, y = 0, z = 25 - 25 * c;
  const Rt = [[c, 0, -s], [0, 1, 0], [s, 0, c]];
  const t = Rt.map((r) => -(r[0] * x + r[1] * y + r[2] * z));
  return JSON.stringify({ width: W, height: H, fx: f, fy: f, cx: W / 2, cy: H / 2,
    world_to_camera: [[...Rt[0], t[0]], [...Rt[1], t[1]], [...Rt[2], t[2]], [0, 0, 0, 1]] });
}
const res = {};
for (let r = 0; r < rounds; r++) for (const cfg of configs) {
  const [kind, w] = cfg.split("@"); const W = Number(w), H = Math.round(W * 450 / 800);
  const opts = kind === "u8" ? { accumulate: "unorm8" } : {};
  const { page, info, errors } = await openHarness(b.context, server.url, "webgl2", [W, H], opts);
  const ms = await page.evaluate(async ([url, camj, k, kind]) => {
    const h = window.harness;
    await h.loadUrl(url);
    h.call("set_camera_json", camj);
    if (kind === "blank") h.call("set_profile", { skip_splats: true });
    if (kind === "square") h.call("set_profile", { square_quads: true });
    return (await h.benchFrames(k, 0)).ms;
  }, [`/artifacts/bench/peers_${n}.ply`, cam(W, H), frames, kind]);
  if (errors.length) console.error(errors);
  (res[cfg] ||= []).push(ms);
  console.log(JSON.stringify({ round: r, cfg, n, ms: +ms.toFixed(1) }));
  await page.close();
}
console.log(JSON.stringify(res));
await b.close(); await server.close();
