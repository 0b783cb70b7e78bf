// The README's generate-mode image, as the page renders it: `node tests/browser/readme-shot.mjs` (NODE_PATH =
// package-config/node_modules; the wasm bundle built by wasm/build.sh). Starts the playground on a free port with
// the shipped weights, opens the page on the default scenario (default mode: generate), waits until the scene is
// generated, streamed and drawn (WebGL2), and writes web/docs/img/playground_generate.png. Not a test (no .test.mjs):
// run it when the shipped weights change.
import { join } from "node:path";
import { startServer, ROOT } from "./lib/playground-server.mjs";
import { launch, openPage } from "./lib/playground-browser.mjs";

const server = await startServer({ warm: false });
const browser = await launch();
try {
  const { page } = await openPage(browser.context, `${server.url}/?backend=webgl2`);
  await page.evaluate(() => window.playground.ready);
  const st = await page.evaluate(() => ({ mode: window.playground.state.sceneMode, err: window.playground.state.lastError }));
  if (st.err) throw new Error(`page error: ${st.err}`);
  if (st.mode !== "generate") throw new Error(`the page served mode ${st.mode}, not generate`);
  const out = join(ROOT, "web/docs/img/playground_generate.png");
  await page.screenshot({ path: out });
  console.log(`wrote ${out} (mode ${st.mode})`);
} finally {
  await browser.close();
  await server.stop();
}
