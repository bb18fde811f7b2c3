// The dashboard page in headless Chromium (Playwright, playwright-core), driven by
// run_e2e.sh, which has started flexidd (knowing S1 and S2, refusing other actuators) and
// flexid-dashboard and identified model MODEL_VERSION for actuator S1. Environment:
// DASHBOARD_URL, RIG (flexid-rig), CONTROL (flexid-control), FLEXID (the command line),
// LCM_URL, RIG_START_UTIME,
// MODEL_VERSION, CHROMIUM, SCREENSHOT, optional FLEXID_DOCS_SCREENSHOT; FLEXID_KEY_FILE
// signs the command line's changes.
//
// Checks: the page loads with no error and no request to anywhere but the dashboard; while
// the rig plays a fresh 2 V trial, S1's charts update (the point counter grows, three
// uPlot canvases) and the model line shows the identified version and its fit; S1's model
// versions list the identified one, active. An actuator with no model: the rig publishes
// S2 (known to flexidd, no model) and S3 (refused by flexidd: no prediction at all); their
// deflection charts' data grow reading after reading, with no predicted line and no
// residual chart. When the rig turns on back-relaxation, a back_relaxation alert appears in
// S1's card and in the feed; `flexid diagnose --actuator S1 --trial N --propose` stores the
// augmented model, which the page lists as an inactive proposal on MODEL_VERSION with its
// effect and held-out gain; `flexid models activate` makes it the active one on the page,
// and a replay of the trial runs on it. Last, flexid-control makes the rig (in closed loop,
// with the back-relaxation the proposal holds) follow a staircase: S1's deflection chart
// draws the reference (its reference points grow while the run goes on) beside the
// measured and predicted lines, and the readout shows it. Then a screenshot. Exit 0 passed, 1 failed (with
// dashboard-failure.png).
import {execFile, spawn} from 'node:child_process';
import {copyFileSync, mkdirSync} from 'node:fs';
import path from 'node:path';
import {chromium} from 'playwright-core';

const env = process.env;
for (const name of ['DASHBOARD_URL', 'RIG', 'CONTROL', 'FLEXID', 'LCM_URL', 'RIG_START_UTIME', 'MODEL_VERSION',
  'SCREENSHOT']) {
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

// One rig run on the bus, as deploy/demo runs it; resolves when the rig exits 0. Trial
// control for S1 only: flexidd refuses S3 (and its trials).
function runRig(protocol, extra = [], actuators = 'S1') {
  const args = ['--lcm', env.LCM_URL, '--actuator', actuators, '--speed', '100', '--noise-mm', '0.02',
    ...(actuators === 'S1' ? ['--trial-control'] : []),
    '--start-utime', String(startUtime), '--protocol', protocol, ...extra];
  startUtime += 500000000n;
  return new Promise((resolve, reject) => {
    const child = spawn(env.RIG, args, {stdio: ['ignore', 'ignore', 'inherit']});
    child.on('error', reject);
    child.on('exit', (code) => (code === 0 ? resolve() : reject(new Error(`flexid-rig exited ${code}`))));
  });
}

// A closed-loop run: flexid-control follows `protocol` (a reference in mm) on S1 with the
// active model, the rig in closed loop for `duration_s` (longer than the reference) plays
// the back-relaxation the proposal holds; resolves when both exit 0 (the reference
// followed to its end).
function runControl(protocol, duration_s) {
  const exit = (child, name) => new Promise((resolve, reject) => {
    child.on('error', reject);
    child.on('exit', (code) => (code === 0 ? resolve() : reject(new Error(`${name} exited ${code}`))));
  });
  const control = spawn(env.CONTROL, ['--lcm', env.LCM_URL, '--actuator', 'S1', '--protocol', protocol],
    {stdio: ['ignore', 'ignore', 'inherit']});
  const controlled = exit(control, 'flexid-control');
  const rigArgs = ['--lcm', env.LCM_URL, '--actuator', 'S1', '--closed-loop', '--duration', String(duration_s),
    '--speed', '10', '--noise-mm', '0.02', '--trial-control', '--start-utime', String(startUtime),
    '--effect', 'back_relaxation:fraction=0.3,tau=60'];
  startUtime += 500000000n;
  return sleep(300).then(() => {
    const rig = spawn(env.RIG, rigArgs, {stdio: ['ignore', 'ignore', 'inherit']});
    return Promise.all([controlled, exit(rig, 'flexid-rig')]);
  });
}

// `flexid ARGS...` on the test's bus; resolves with its stdout when it exits 0.
function flexid(args, timeoutMs = 120000) {
  return new Promise((resolve, reject) => {
    execFile(env.FLEXID, ['--lcm', env.LCM_URL, ...args], {timeout: timeoutMs, maxBuffer: 1 << 24},
      (error, stdout, stderr) => {
        if (error) reject(new Error(`flexid ${args.join(' ')}: ${stderr.trim() || error.message}`));
        else resolve(stdout);
      });
  });
}

const points = (page) => page.$eval(S1, (card) => Number(card.dataset.points));
const card = (id) => `.card[data-actuator="${id}"]`;
const chartPoints = (page, id) => page.$eval(card(id), (c) => Number(c.dataset.chartPoints));
const referencePoints = (page) => page.$eval(S1, (c) => Number(c.dataset.referencePoints));
// The text of an element's innermost parts, " · " between them (for the log and checks).
const oneLine = (page, selector) => page.$eval(selector, (node) =>
  [...node.querySelectorAll('*')].filter((n) => n.children.length === 0 && n.textContent.trim())
    .map((n) => n.textContent.replace(/\s+/g, ' ').trim()).join(' · '));
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

const browser = await chromium.launch({
  executablePath: env.CHROMIUM || '/usr/bin/chromium',
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
// Wide enough for two columns of cards beside the alert feed.
const page = await browser.newPage({viewport: {width: 1600, height: 1000}});
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
      `model line: ${await oneLine(page, `${S1} .model`)}`);
  const predicted = await page.textContent(`${S1} .readout`);
  if (!/predicted-?[0-9.]+mm/.test(predicted.replace(/\s+/g, ''))) throw new Error(`no prediction shown: ${predicted}`);
  await page.waitForSelector(
    `${S1} .versions .version[data-version="${version}"][data-active="true"][data-kind="identified"]`,
    {timeout: 15000});
  log(`versions: ${await oneLine(page, `${S1} .versions`)}`);
  await fresh;

  // Actuators with no model: S2 (flexidd knows it, has no model) and S3 (flexidd refuses
  // it, so nothing but the source's samples is on the bus). Their charts grow from the
  // samples: the measured points in the chart data, read while the rig plays.
  const bare = runRig('square:level=4,period=220,duty=0.5,cycles=2', [], 'S2,S3');
  let rigDone = false;
  bare.then(() => { rigDone = true; }, () => { rigDone = true; });
  await page.waitForSelector(`${card('S2')}[data-chart-points]:not([data-chart-points="0"])`, {timeout: 30000});
  await page.waitForSelector(`${card('S3')}[data-chart-points]:not([data-chart-points="0"])`, {timeout: 30000});
  const readings = {S2: [], S3: []};
  while (!rigDone && readings.S2.length < 6) {
    for (const id of ['S2', 'S3']) readings[id].push(await chartPoints(page, id));
    await sleep(400);
  }
  await bare;
  for (const id of ['S2', 'S3']) {
    const r = readings[id];
    const grew = r.length >= 3 && r.every((n, i) => i === 0 || n > r[i - 1]);
    if (!grew) throw new Error(`${id}'s chart did not grow while the rig played: ${r.join(' -> ')}`);
    const c = card(id);
    if ((await page.getAttribute(c, 'data-predicted')) !== 'false') throw new Error(`${id} shows predictions`);
    if (await page.isVisible(`${c} .chart-residual`)) throw new Error(`${id} shows a residual chart`);
    if (await page.locator(`${c} .chart-deflection canvas`).count() < 1) throw new Error(`${id} has no deflection chart`);
    if (!(await page.isVisible(`${c} .model .model-none`))) throw new Error(`${id}'s model line: ${await oneLine(page, `${c} .model`)}`);
    const readout = await oneLine(page, `${c} .readout`);
    if (!/measured/.test(readout) || /predicted/.test(readout)) throw new Error(`${id}'s readout: ${readout}`);
    log(`${id} without a model: chart points ${r.join(' -> ')}; readout: ${readout}`);
  }
  // S2: flexidd answered, no version; S3: flexidd's refusal is shown.
  await page.waitForSelector(`${card('S2')} .versions[data-loaded="true"]`, {timeout: 15000});
  if (await page.locator(`${card('S2')} .version`).count() !== 0) throw new Error('S2 lists model versions');
  await page.waitForFunction((c) => /unknown actuator/.test(document.querySelector(`${c} .versions`).textContent),
    card('S3'), {timeout: 15000});
  log(`S2: ${await oneLine(page, `${card('S2')} .versions`)}; S3: ${await oneLine(page, `${card('S3')} .versions`)}`);

  // An alert when the rig turns on back-relaxation.
  const relaxing = runRig('square:level=2,period=220,duty=0.5,cycles=2',
    ['--effect', 'back_relaxation:fraction=0.3,tau=60']);
  await page.waitForSelector(`${S1} .alert[data-kind="back_relaxation"]`, {timeout: 60000});
  await page.waitForSelector('#alerts .alert[data-kind="back_relaxation"]', {timeout: 5000});
  log(`alert: ${(await page.textContent(`${S1} .alert[data-kind="back_relaxation"] .alert-text`)).trim()}`);
  await relaxing;

  // A proposal: the relaxing trial diagnosed and its augmented model stored, inactive.
  let trial = null;
  for (let i = 0; i < 50 && !trial; i++) {
    const [latest] = JSON.parse(await flexid(['rpc', 'trials', '{"actuator": "S1", "limit": 1}']));
    if (latest && latest.state === 'complete') trial = latest.id;
    else await sleep(200);
  }
  if (!trial) throw new Error('the back-relaxation trial did not end as complete');
  // flexidd's own policy (on_alert = diagnose) may be diagnosing the trial: wait for it.
  let diagnosis = null;
  for (let i = 0; !diagnosis; i++) {
    try {
      diagnosis = JSON.parse(await flexid(
        ['diagnose', '--actuator', 'S1', '--trial', String(trial), '--propose', '--json'], 240000));
    } catch (error) {
      if (i >= 60 || !/already running/.test(error.message)) throw error;
      await sleep(1000);
    }
  }
  const proposed = diagnosis.proposed_version;
  if (!(proposed > Number(version))) throw new Error(`nothing proposed: ${JSON.stringify(diagnosis).slice(0, 400)}`);
  const proposal = `${S1} .versions .version[data-version="${proposed}"]`;
  await page.waitForSelector(`${proposal}[data-kind="proposed"][data-active="false"][data-parent="${version}"]`,
    {timeout: 15000});
  const proposalText = await oneLine(page, proposal);
  for (const words of [`proposed from v${version}`, 'back relaxation', 'held-out RMSE', '×', `trial ${trial}`])
    if (!proposalText.includes(words)) throw new Error(`the proposal's line lacks "${words}": ${proposalText}`);
  log(`proposal on trial ${trial}: ${proposalText}`);

  // Activated with the command line (a signed change): the page shows it active.
  await flexid(['models', 'activate', '--actuator', 'S1', String(proposed)]);
  await page.waitForSelector(`${proposal}[data-active="true"]`, {timeout: 15000});
  await page.waitForSelector(`${S1} .versions .version[data-version="${version}"][data-active="false"]`,
    {timeout: 5000});
  await page.waitForSelector(`#alerts .alert[data-kind="model_changed"]`, {timeout: 5000});
  log(`activated: ${await oneLine(page, `${S1} .versions`)}`);

  // The same trial again, predicted by the proposal.
  const replay = runRig('square:level=2,period=220,duty=0.5,cycles=2',
    ['--effect', 'back_relaxation:fraction=0.3,tau=60']);
  await page.waitForSelector(`${S1} .model[data-model-version="${proposed}"]`, {timeout: 60000});
  await replay;
  log(`model line: ${await oneLine(page, `${S1} .model`)}`);

  // Under control: the reference beside the measured and predicted deflection.
  if ((await page.getAttribute(S1, 'data-controlled')) !== 'false') throw new Error('S1 shows a reference before any control');
  let controlDone = false;
  const control = runControl('staircase:levels=10/15,dwell=40', 140);  // 120 s: 10, 15, then 0 mm
  control.then(() => { controlDone = true; }, () => { controlDone = true; });
  await page.waitForSelector(`${S1}[data-controlled="true"]`, {timeout: 30000});
  const referenceReadings = [];
  let referenceReadout = '';
  while (!controlDone && referenceReadings.length < 6) {
    referenceReadings.push(await referencePoints(page));
    const readout = await oneLine(page, `${S1} .readout`);
    if (/reference/.test(readout)) referenceReadout = readout;
    await sleep(500);
  }
  await control;
  const rr = referenceReadings;
  if (!(rr.length >= 3 && rr.every((n, i) => i === 0 || n > rr[i - 1])))
    throw new Error(`S1's reference did not grow while under control: ${rr.join(' -> ')}`);
  if (!/reference · (10|15)(\.[0-9]+)? mm/.test(referenceReadout)) throw new Error(`no reference in S1's readout: ${referenceReadout}`);
  log(`under control: reference points ${rr.join(' -> ')}; readout: ${referenceReadout}`);
  await page.waitForTimeout(1000);  // the last batch drawn, the alerts' flash over

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
