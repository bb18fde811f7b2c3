// The dashboard page in headless Chromium (Playwright, playwright-core), driven by
// run_e2e.sh, which has started flexidd and flexid-dashboard and identified model
// MODEL_VERSION for actuator S1. Environment: DASHBOARD_URL, RIG (flexid-rig), LCM_URL,
// RIG_START_UTIME, MODEL_VERSION, CHROMIUM, SCREENSHOT, optional FLEXID_DOCS_SCREENSHOT.
//
// Checks: the page loads with no error and no request to anywhere but the dashboard; while
// the rig plays a fresh 2 V trial, S1's charts update (the point counter grows, three
// uPlot canvases) and the model line shows the identified version and its fit; when the
// rig turns on back-relaxation, a back_relaxation alert appears in S1's card and in the
// feed. Then a screenshot. Exit 0 passed, 1 failed (with dashboard-failure.png).
import {spawn} from 'node:child_process';
import {copyFileSync, mkdirSync} from 'node:fs';
import path from 'node:path';
import {chromium} from 'playwright-core';

const env = process.env;
for (const name of ['DASHBOARD_URL', 'RIG', 'LCM_URL', 'RIG_START_UTIME', 'MODEL_VERSION', 'SCREENSHOT']) {
  if (!env[name]) {
    console.error(`e2e.mjs: ${name} is not set (run tests/dashboard/run_e2e.sh)`);
    process.exit(1);
  }
}
const origin = new URL(env.DASHBOARD_URL).origin;
const version = String(env.MODEL_VERSION);
let startUtime = BigInt(env.RIG_START_UTIME);
const S1 = '.card[data-actuator="S1"]';

function log(message) {
  console.log(`dashboard_e2e: ${message}`);
}

// One rig run on the bus, as deploy/demo runs it; resolves when the rig exits 0.
function runRig(protocol, extra = []) {
  const args = ['--lcm', env.LCM_URL, '--actuator', 'S1', '--speed', '100', '--noise-mm', '0.02',
    '--trial-control', '--start-utime', String(startUtime), '--protocol', protocol, ...extra];
  startUtime += 500000000n;
  return new Promise((resolve, reject) => {
    const child = spawn(env.RIG, args, {stdio: ['ignore', 'ignore', 'inherit']});
    child.on('error', reject);
    child.on('exit', (code) => (code === 0 ? resolve() : reject(new Error(`flexid-rig exited ${code}`))));
  });
}

const points = (page) => page.$eval(S1, (card) => Number(card.dataset.points));

const browser = await chromium.launch({
  executablePath: env.CHROMIUM || '/usr/bin/chromium',
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
const page = await browser.newPage({viewport: {width: 1440, height: 1000}});
const problems = [];
page.on('console', (message) => {
  if (message.type() === 'error') problems.push(`console: ${message.text()}`);
});
page.on('pageerror', (error) => problems.push(`page error: ${error.message}`));
page.on('request', (request) => {
  if (new URL(request.url()).origin !== origin) problems.push(`request elsewhere: ${request.url()}`);
});

try {
  // A 15-minute window shows both of the last trials whole (the rig runs x100).
  await page.goto(`${env.DASHBOARD_URL}?window_s=900`, {waitUntil: 'load'});
  await page.waitForSelector('#connection[data-state="live"]', {timeout: 15000});
  if (!(await page.evaluate(() => typeof uPlot === 'function'))) throw new Error('uPlot did not load');
  await page.waitForSelector(S1, {timeout: 15000});
  log(`page live; S1 shows ${await points(page)} points from the recorded trials`);

  // Charts update as the rig publishes a fresh trial.
  const before = await points(page);
  const fresh = runRig('square:level=2,period=220,duty=0.5,cycles=2');
  await page.waitForFunction(
    ([selector, count]) => Number(document.querySelector(selector).dataset.points) > count + 100,
    [S1, before], {timeout: 60000});
  const canvases = await page.locator(`${S1} canvas`).count();
  if (canvases < 3) throw new Error(`expected 3 uPlot canvases in S1's card, found ${canvases}`);
  await page.waitForFunction(
    ([selector, v]) => {
      const model = document.querySelector(`${selector} .model`);
      return model && model.dataset.modelVersion === v && /fit [0-9.]+ %/.test(model.textContent);
    },
    [S1, version], {timeout: 60000});
  log(`charts update (${before} -> ${await points(page)} points, ${canvases} canvases); ` +
      `model line: ${(await page.textContent(`${S1} .model`)).replace(/\s+/g, ' ').trim()}`);
  const predicted = await page.textContent(`${S1} .readout`);
  if (!/predicted-?[0-9.]+mm/.test(predicted.replace(/\s+/g, ''))) throw new Error(`no prediction shown: ${predicted}`);
  await fresh;

  // An alert when the rig turns on back-relaxation.
  const relaxing = runRig('square:level=2,period=220,duty=0.5,cycles=2',
    ['--effect', 'back_relaxation:fraction=0.3,tau=60']);
  await page.waitForSelector(`${S1} .alert[data-kind="back_relaxation"]`, {timeout: 60000});
  await page.waitForSelector('#alerts .alert[data-kind="back_relaxation"]', {timeout: 5000});
  log(`alert: ${(await page.textContent(`${S1} .alert[data-kind="back_relaxation"] .alert-text`)).trim()}`);
  await relaxing;
  await page.waitForTimeout(1000);  // the last batch drawn, the alert's flash over

  if (problems.length) throw new Error(problems.join('\n'));
  mkdirSync(path.dirname(env.SCREENSHOT), {recursive: true});
  await page.screenshot({path: env.SCREENSHOT, fullPage: true});
  log(`screenshot ${env.SCREENSHOT}`);
  if (env.FLEXID_DOCS_SCREENSHOT) {
    copyFileSync(env.SCREENSHOT, env.FLEXID_DOCS_SCREENSHOT);
    log(`screenshot ${env.FLEXID_DOCS_SCREENSHOT}`);
  }
  log('passed');
} catch (error) {
  process.exitCode = 1;
  console.error(`dashboard_e2e: FAILED: ${error.message}`);
  if (problems.length) console.error(problems.join('\n'));
  const failure = path.join(path.dirname(env.SCREENSHOT), 'dashboard-failure.png');
  await page.screenshot({path: failure, fullPage: true}).catch(() => {});
  console.error(`dashboard_e2e: screenshot of the failure: ${failure}`);
} finally {
  await browser.close();
}
