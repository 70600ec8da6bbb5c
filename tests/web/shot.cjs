// Drive Debian's chromium headless (WebGL through SwiftShader) over the viewer page:
// for each view open its URL, wait until window.approxtree.ready (tiles loaded and a few
// frames drawn) or an error, take a screenshot and collect Cesium's statistics and the
// requests the page made. Requests to anything but 127.0.0.1 are blocked and reported.
//   node shot.cjs JOB.json    (JOB: {node_modules, chromium, width, height, timeout_ms,
//                               views: [{url, screenshot}]})   -> JSON on stdout
"use strict";
const fs = require("fs");
const path = require("path");

async function main() {
  const job = JSON.parse(fs.readFileSync(process.argv[2], "utf8"));
  const { chromium } = require(path.join(job.node_modules, "playwright-core"));
  const browser = await chromium.launch({
    executablePath: job.chromium,
    headless: true,
    args: [
      "--use-angle=swiftshader",
      "--enable-unsafe-swiftshader",
      "--ignore-gpu-blocklist",
      "--enable-webgl",
      "--no-sandbox",
      "--disable-dev-shm-usage",
    ],
  });
  const results = [];
  try {
    for (const view of job.views) {
      const context = await browser.newContext({
        viewport: { width: job.width, height: job.height },
        deviceScaleFactor: 1,
      });
      const page = await context.newPage();
      const requests = [];
      const blocked = [];
      const failed = [];
      const consoleErrors = [];
      // The page must reach nothing but the local server.
      await page.route("**/*", (route) => {
        const url = route.request().url();
        if (/^https?:\/\/127\.0\.0\.1[:/]/.test(url) || url.startsWith("data:") || url.startsWith("blob:")) {
          return route.continue();
        }
        blocked.push(url);
        return route.abort();
      });
      page.on("request", (r) => requests.push(r.url()));
      page.on("requestfailed", (r) => failed.push(r.url()));
      page.on("console", (m) => {
        if (m.type() === "error") consoleErrors.push(m.text());
      });
      page.on("pageerror", (e) => consoleErrors.push(String(e)));
      const started = Date.now();
      let state = { ready: false, error: null };
      try {
        await page.goto(view.url, { waitUntil: "load", timeout: job.timeout_ms });
        await page.waitForFunction(
          () => window.approxtree && (window.approxtree.ready || window.approxtree.error),
          null,
          { timeout: job.timeout_ms, polling: 100 },
        );
        state = await page.evaluate(() => ({
          ready: window.approxtree.ready,
          error: window.approxtree.error,
          stats: window.approxtree.ready ? window.approxtree.statistics() : null,
          statsAtReady: window.approxtree.stats || null,
          webgl2: !!document.createElement("canvas").getContext("webgl2"),
        }));
      } catch (e) {
        state.error = "timeout or navigation error: " + e.message;
      }
      if (view.screenshot) await page.screenshot({ path: view.screenshot });
      results.push({
        url: view.url,
        seconds: (Date.now() - started) / 1000,
        ...state,
        requests,
        blocked,
        failed,
        consoleErrors,
      });
      await context.close();
    }
  } finally {
    await browser.close();
  }
  process.stdout.write(JSON.stringify({ views: results }));
}

main().catch((e) => {
  process.stdout.write(JSON.stringify({ error: String(e && e.stack ? e.stack : e) }));
  process.exit(1);
});
