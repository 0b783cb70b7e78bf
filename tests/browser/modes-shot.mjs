// The three modes of one scenario as the page draws them, stacked (oracle, reconstruct, generate):
// `node tests/browser/modes-shot.mjs` (NODE_PATH = package-config/node_modules; the wasm bundle built by wasm/build.sh).
// Starts the playground with the shipped weights, opens the page on the default scenario (WebGL2, a 1400x900
// window, as a new user would), generates it in each mode, puts frame 0 on the front camera, shoots the viewer's
// canvas and writes web/docs/img/page_modes.png (the same layout as ../shared/evidence/page-modes.png, to compare
// with it). Not a test (no .test.mjs): run it when the served scene changes, and look at the image.
import { join } from "node:path";
import { startServer, ROOT } from "./lib/playground-server.mjs";
import { launch, openPage, showFrame } from "./lib/playground-browser.mjs";

const MODES = ["oracle", "reconstruct", "generate"];

const server = await startServer({ warm: false });
const browser = await launch();
try {
  const { page } = await openPage(browser.context, `${server.url}/?backend=webgl2`);
  await page.setViewportSize({ width: 1400, height: 900 });
  await page.evaluate(() => window.playground.ready);
  const shots = [];
  for (const mode of MODES) {
    await page.evaluate((m) => window.playground.generate(window.playground.readForm(), m), mode);
    const st = await page.evaluate(() => ({ mode: window.playground.state.sceneMode, err: window.playground.state.lastError }));
    if (st.err) throw new Error(`page error in ${mode}: ${st.err}`);
    if (st.mode !== mode) throw new Error(`the page served mode ${st.mode}, not ${mode}`);
    await showFrame(page, 0);
    shots.push((await page.locator("#canvas").screenshot()).toString("base64"));
    console.log(`shot ${mode}`);
  }
  // Stack the three shots in one image: a blank page of <img>s, shot whole (no image library needed).
  const sheet = await browser.context.newPage();
  await sheet.setContent(`<body style="margin:0;background:#000"><div id="sheet" style="display:inline-block">${shots
    .map((b) => `<img style="display:block" src="data:image/png;base64,${b}">`).join("")}</div></body>`);
  await sheet.waitForFunction(() => [...document.images].every((i) => i.complete && i.naturalWidth > 0));
  const out = join(ROOT, "web/docs/img/page_modes.png");
  await sheet.locator("#sheet").screenshot({ path: out });
  console.log(`wrote ${out}`);
} finally {
  await browser.close();
  await server.stop();
}
