// Drives `fpm serve`'s page in Debian's headless Chromium as a person would: open the
// address the service printed, start an acquisition, watch its progress and its final
// image, then start a second, pause it, resume it, cancel it mid-capture, complete it
// with the history's Resume button, and open the page again to see the last result.
// Prints what it saw as one JSON object on stdout; tests/tests/serve.rs judges it (this script asserts nothing).
//
//   node tools/browser/serve-page.mjs PAGE_URL SCREENSHOT.png

import { chromium } from "playwright-core";

const [pageUrl, screenshot] = process.argv.slice(2);
if (!pageUrl || !screenshot) {
  console.error("usage: node serve-page.mjs PAGE_URL SCREENSHOT.png");
  process.exit(2);
}

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
  ],
});
const seen = { errors: [], progress: [] };

// The mean and standard deviation of the grey levels the browser drew for image `id`
// (run in the page).
function greyStats(id) {
  const img = document.getElementById(id);
  const canvas = document.createElement("canvas");
  canvas.width = img.naturalWidth;
  canvas.height = img.naturalHeight;
  const ctx = canvas.getContext("2d");
  ctx.drawImage(img, 0, 0);
  const { data } = ctx.getImageData(0, 0, canvas.width, canvas.height);
  let sum = 0, sum2 = 0;
  const n = data.length / 4;
  for (let i = 0; i < data.length; i += 4) {
    sum += data[i];
    sum2 += data[i] * data[i];
  }
  const mean = sum / n;
  return { width: img.naturalWidth, height: img.naturalHeight, mean, std: Math.sqrt(sum2 / n - mean * mean) };
}
try {
  const page = await browser.newPage({ viewport: { width: 1200, height: 1400 } });
  page.on("pageerror", (e) => seen.errors.push("page error: " + e.message));
  page.on("console", (m) => {
    if (m.type() === "error") seen.errors.push("console: " + m.text());
  });
  await page.goto(pageUrl);
  await page.waitForSelector('body[data-connected="true"]', { timeout: 10_000 });
  seen.address_after_load = page.url();
  seen.rig = await page.textContent("#rig");

  // The first acquisition, from the form.
  await page.fill('input[name="step_ms"]', "15");
  await page.fill('input[name="snapshot_every"]', "40");
  await page.click("#start");
  await page.waitForSelector("body[data-last-submitted]", { timeout: 10_000 });
  const first = Number(await page.getAttribute("body", "data-last-submitted"));
  seen.first = first;
  const row = (id) => `tr[data-job="${id}"]`;
  // Progress as the page shows it, sampled until the job's row says it ended.
  const ended = (id) =>
    page.evaluate((sel) => {
      const r = document.querySelector(sel);
      return r ? r.dataset.state : null;
    }, row(id));
  const start = Date.now();
  for (;;) {
    const value = await page.evaluate(() => document.getElementById("progress").value);
    if (seen.progress.length === 0 || seen.progress[seen.progress.length - 1] !== value) {
      seen.progress.push(value);
    }
    const state = await ended(first);
    if (state && !["queued", "running"].includes(state)) {
      seen.first_state = state;
      break;
    }
    if (Date.now() - start > 120_000) {
      seen.first_state = "timed out: " + state;
      break;
    }
    await page.waitForTimeout(100);
  }
  // The final image: announced, loaded, and not blank (its pixels' spread, read back
  // through a canvas).
  await page.waitForSelector(`body[data-snapshot-job="${first}"][data-snapshot-finished="true"]`, {
    timeout: 10_000,
  });
  await page.waitForFunction(() => {
    const img = document.getElementById("amplitude");
    return img.complete && img.naturalWidth > 0 && img.src.includes("seq=");
  }, null, { timeout: 10_000 });
  seen.final_image = await page.evaluate(greyStats, "amplitude");
  seen.caption = await page.textContent("#amplitude-caption");
  seen.report_links = await page.$$eval(`${row(first)} a`, (links) => links.map((a) => a.getAttribute("href")));

  // A second acquisition, cancelled from the page once frames come in.
  await page.fill('input[name="step_ms"]', "40");
  await page.click("#start");
  await page.waitForFunction((f) => Number(document.body.dataset.lastSubmitted) > f, first, {
    timeout: 10_000,
  });
  const second = Number(await page.getAttribute("body", "data-last-submitted"));
  seen.second = second;
  await page.waitForFunction(
    (id) => document.body.dataset.running === String(id) && Number(document.body.dataset.frames) >= 20,
    second,
    { timeout: 60_000 },
  );
  // Paused: the page says so and no frame comes while it holds; resumed: frames again.
  await page.click("#pause");
  await page.waitForFunction(() => document.getElementById("progress-text").textContent.startsWith("paused"), null, {
    timeout: 10_000,
  });
  seen.pause_button = await page.textContent("#pause");
  seen.frames_paused = Number(await page.getAttribute("body", "data-frames"));
  await page.waitForTimeout(800);
  seen.frames_paused_later = Number(await page.getAttribute("body", "data-frames"));
  await page.click("#pause");
  await page.waitForFunction((n) => Number(document.body.dataset.frames) >= n + 10, seen.frames_paused, {
    timeout: 30_000,
  });
  seen.frames_at_cancel = Number(await page.getAttribute("body", "data-frames"));
  await page.click("#cancel");
  await page.waitForFunction(
    (sel) => {
      const r = document.querySelector(sel);
      return r && !["queued", "running"].includes(r.dataset.state);
    },
    row(second),
    { timeout: 30_000 },
  );
  seen.second_state = await page.getAttribute(row(second), "data-state");
  seen.second_text = await page.textContent(row(second));
  // Completed from the history: a resume job lights the LEDs the cancel left.
  await page.click(`${row(second)} button.resume`);
  await page.waitForFunction(
    (f) => [...document.querySelectorAll("tr[data-job]")].some((r) => Number(r.dataset.job) > f),
    second,
    { timeout: 10_000 },
  );
  const third = await page.evaluate(() => Math.max(...[...document.querySelectorAll("tr[data-job]")].map((r) => Number(r.dataset.job))));
  seen.third = third;
  await page.waitForFunction(
    (sel) => {
      const r = document.querySelector(sel);
      return r && !["queued", "running"].includes(r.dataset.state);
    },
    row(third),
    { timeout: 90_000 },
  );
  seen.third_state = await page.getAttribute(row(third), "data-state");
  seen.third_kind = await page.textContent(`${row(third)} td:nth-child(2)`);
  // Opened again, as a lab opens it in the morning: the newest finished job's
  // result is on the page, not grey boxes.
  await page.reload();
  await page.waitForFunction(() => {
    const img = document.getElementById("amplitude");
    return document.body.dataset.resultJob !== undefined && img.complete && img.naturalWidth > 0;
  }, null, { timeout: 10_000 });
  seen.result_job = Number(await page.getAttribute("body", "data-result-job"));
  seen.result_caption = await page.textContent("#amplitude-caption");
  seen.result_image = await page.evaluate(greyStats, "amplitude");
  // The history: the first job's row with its result's thumbnail and key numbers.
  await page.waitForFunction((r) => {
    const img = document.querySelector(r + " img.thumb");
    const facts = document.querySelector(r + ' .facts[data-filled="true"]');
    return img && img.complete && img.naturalWidth > 0 && facts;
  }, row(first), { timeout: 10_000 });
  seen.history_thumb_width = await page.$eval(`${row(first)} img.thumb`, (img) => img.naturalWidth);
  seen.history_facts = await page.textContent(`${row(first)} .facts`);
  await page.screenshot({ path: screenshot, fullPage: true });
} catch (e) {
  seen.errors.push("driver: " + e.message);
} finally {
  await browser.close();
}
console.log(JSON.stringify(seen));
