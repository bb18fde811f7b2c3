// flexid-dashboard's page: one card per actuator with uPlot charts of voltage, measured and
// predicted deflection and residual over the last minutes of message time, the active
// model and its fit, the actuator's model versions (identified and proposed), and the
// alerts as they arrive. An actuator without predictions (no model yet) shows its voltage
// and measured deflection; the predicted line and the residual chart appear once
// predictions flow. An actuator under control (flexid-control) also has its reference
// drawn in the deflection chart, from the commands' reference series.
//
// Data flow: GET /api/state (a snapshot, with the id of the last event it contains), then
// an EventSource on /events?after=ID: "points" (batched, decimated points of every
// actuator), "alert", "model", "versions" (an actuator's model version list), "daemon"
// (the flexidd that records an actuator, when several share the bus), and
// "resync" (the stream fell behind: load the snapshot again). When the stream breaks (the
// server restarted), the page loads the snapshot again and reopens the stream, waiting
// 1 s, then up to 10 s, between tries.
//
// Hooks for tests: .card[data-actuator=ID] with data-points (points drawn so far),
// data-chart-points (measured points in the deflection chart's data now),
// data-reference-points (reference values in it now), data-controlled ("true" once a
// reference came), data-received
// (predictions the server took), data-samples (deflection samples it took),
// data-predicted ("true" once predictions show), data-model-version, data-daemon (the
// flexidd recording it, shown as .daemon); in each card
// .versions[data-loaded] holding li.version[data-version][data-active][data-kind
// identified|proposed][data-parent]; .alert[data-kind] in each card and in #alerts;
// #connection[data-state] is connecting, live or reconnecting.
'use strict';

(() => {
  const MAX_POINTS = 20000;  // per series, whatever the window
  const MAX_ALERTS = 100;    // per list
  const MAX_VERSIONS = 6;    // model versions listed per card, newest first
  const CHART_HEIGHT = 150;
  const GAP_S = 20;  // a pause this long in message time breaks the lines (no data, no line)
  const COLORS = {
    voltage: '#b45309',
    measured: '#2563eb',
    predicted: '#dc2626',
    residual: '#7c3aed',
    reference: '#111827',
  };
  // A reference sample stands for the points up to this long after it (message time): the
  // reference comes from the command that answers a sample, so it shares the sample's time,
  // but decimation may keep a neighbour instead.
  const REFERENCE_HOLD_S = 2;

  const cards = new Map();  // actuator id -> card
  const daemons = new Map();  // actuator id -> the flexidd that records it
  const alertKeys = new Set();
  let windowS = 60;
  let source = null;
  let retryTimer = null;
  let retryMs = 1000;
  let drawQueued = false;

  const $ = (id) => document.getElementById(id);

  function el(tag, className, text) {
    const node = document.createElement(tag);
    if (className) node.className = className;
    if (text !== undefined) node.textContent = text;
    return node;
  }

  function fmt(x, digits) {
    if (x === null || x === undefined || !Number.isFinite(x)) return '–';
    return Number(x).toPrecision(digits).replace(/(\.\d*?)0+$/, '$1').replace(/\.$/, '');
  }

  function clock(t_s) {
    const d = new Date(t_s * 1000);
    return d.toLocaleTimeString([], {hour12: false}) + '.' + String(d.getMilliseconds()).padStart(3, '0').slice(0, 1);
  }

  // ---- charts ----------------------------------------------------------------------

  function makePlot(container, label, series) {
    const opts = {
      width: Math.max(container.clientWidth, 200),
      height: CHART_HEIGHT,
      scales: {x: {time: true}},
      legend: {live: true},
      cursor: {drag: {x: false, y: false}},
      axes: [
        {stroke: '#64748b', grid: {stroke: '#eef2f7'}, ticks: {stroke: '#e2e8f0'}},
        {stroke: '#64748b', grid: {stroke: '#eef2f7'}, ticks: {stroke: '#e2e8f0'}, size: 56,
         label, labelSize: 18, labelFont: '12px system-ui, sans-serif'},
      ],
      series: [{label: 'time'}].concat(series.map((s) => ({
        label: s.label,
        stroke: s.color,
        width: s.width || 1.5,
        dash: s.dash,
        paths: s.stepped ? uPlot.paths.stepped({align: 1}) : undefined,
        points: {show: false},
        value: (u, v) => (v === null || v === undefined ? '–' : fmt(v, 4)),
      }))),
    };
    return new uPlot(opts, [[]].concat(series.map(() => [])), container);
  }

  function newCard(id) {
    const root = el('article', 'card');
    root.dataset.actuator = id;
    root.dataset.points = '0';
    root.dataset.received = '0';
    root.dataset.samples = '0';
    root.dataset.chartPoints = '0';
    root.dataset.referencePoints = '0';
    root.dataset.controlled = 'false';
    root.dataset.predicted = 'false';
    root.dataset.modelVersion = '0';

    const head = el('header', 'card-head');
    head.append(el('h2', 'name', id));
    const daemon = el('span', 'daemon', '');
    const trial = el('span', 'trial', '');
    const counter = el('span', 'points', '0 points');
    head.append(daemon, trial, counter);

    const readout = el('div', 'readout', 'no sample yet');
    const model = el('div', 'model', 'model: none yet');
    model.dataset.modelVersion = '0';
    const versions = el('div', 'versions');
    versions.dataset.loaded = 'false';
    versions.append(el('span', 'versions-none', 'model versions: asking flexidd…'));

    const charts = el('div', 'charts');
    const boxes = {};
    for (const [key, title] of [['voltage', 'voltage'], ['deflection', 'deflection'], ['residual', 'residual']]) {
      const box = el('div', 'chart chart-' + key);
      box.append(el('div', 'chart-title', title));
      const host = el('div', 'chart-host');
      box.append(host);
      charts.append(box);
      boxes[key] = host;
    }

    const alertsHead = el('h3', 'card-alerts-head', 'Alerts');
    const alerts = el('ol', 'alerts card-alerts');
    const none = el('li', 'none', 'none');
    alerts.append(none);

    root.append(head, readout, model, versions, charts, alertsHead, alerts);
    const list = $('actuators');
    // Cards in id order.
    const after = [...list.querySelectorAll('.card')].find((c) => c.dataset.actuator > id);
    list.insertBefore(root, after || null);
    $('empty').hidden = true;

    const card = {
      id, root, daemon, trial, counter, readout, model, versions, alerts, none,
      data: {t: [], v: [], measured: [], predicted: [], residual: []},
      reference: {t: [], mm: []},  // its own times; null ends a control run
      points: 0,
      predicted: false,  // predictions seen: the predicted line and the residual chart show
      controlled: false,  // a reference seen: its line shows
      modelInfo: null,
      modelVersion: 0,
      dirty: true,
      plots: null,
      boxes,
    };
    card.plots = {
      // The voltage holds until the next sample: drawn as steps.
      voltage: makePlot(boxes.voltage, 'V', [{label: 'voltage V', color: COLORS.voltage, stepped: true}]),
      deflection: makePlot(boxes.deflection, 'mm', [
        {label: 'measured mm', color: COLORS.measured},
        {label: 'predicted mm', color: COLORS.predicted, dash: [6, 4], width: 2},
        {label: 'reference mm', color: COLORS.reference, dash: [2, 3], width: 2},
      ]),
      residual: makePlot(boxes.residual, 'mm', [{label: 'residual mm', color: COLORS.residual}]),
    };
    cards.set(id, card);
    showPredicted(card);
    showControlled(card);
    showModel(card);
    showDaemon(id, daemons.get(id));
    return card;
  }

  // Before any prediction the card charts what the source measures: the residual chart and
  // the predicted line stay hidden rather than empty.
  function showPredicted(c) {
    c.root.dataset.predicted = String(c.predicted);
    c.boxes.residual.parentElement.hidden = !c.predicted;
    c.plots.deflection.setSeries(2, {show: c.predicted});
    if (c.predicted) resizeAll();
  }

  // The reference line shows once the actuator is under control.
  function showControlled(c) {
    c.root.dataset.controlled = String(c.controlled);
    c.plots.deflection.setSeries(3, {show: c.controlled});
  }

  function appendReference(c, cols) {
    if (!cols || !cols.t_s) return;
    const r = c.reference;
    for (let i = 0; i < cols.t_s.length; i++) {
      const last = r.t.length ? r.t[r.t.length - 1] : null;
      if (last !== null && cols.t_s[i] - last > GAP_S) {
        r.t.push(last + 0.001);
        r.mm.push(null);
      }
      r.t.push(cols.t_s[i]);
      r.mm.push(cols.reference_mm[i]);
    }
    if (!c.controlled && cols.reference_mm.some((x) => x !== null && x !== undefined)) {
      c.controlled = true;
      showControlled(c);
    }
    c.dirty = true;
  }

  // The reference at each point's time: the newest reference sample at or before it, within
  // REFERENCE_HOLD_S (else none: no line).
  function referenceAt(c) {
    const t = c.data.t, r = c.reference;
    const out = new Array(t.length).fill(null);
    let j = -1;
    for (let i = 0; i < t.length; i++) {
      while (j + 1 < r.t.length && r.t[j + 1] <= t[i]) j++;
      if (j >= 0 && t[i] - r.t[j] <= REFERENCE_HOLD_S && r.mm[j] !== null && r.mm[j] !== undefined)
        out[i] = r.mm[j];
    }
    return out;
  }

  function notePredicted(c, cols, modelVersion) {
    if (c.predicted) return;
    if (modelVersion > 0 || cols.predicted_mm.some((x) => x !== null && x !== undefined)) {
      c.predicted = true;
      showPredicted(c);
    }
  }

  function card(id) {
    return cards.get(id) || newCard(id);
  }

  function clearData(c) {
    for (const key of Object.keys(c.data)) c.data[key] = [];
    c.reference = {t: [], mm: []};
  }

  function appendColumns(c, cols) {
    const d = c.data;
    const n = cols.t_s.length;
    for (let i = 0; i < n; i++) {
      const last = d.t.length ? d.t[d.t.length - 1] : null;
      if (last !== null && cols.t_s[i] - last > GAP_S) {
        d.t.push(last + 0.001);
        for (const key of ['v', 'measured', 'predicted', 'residual']) d[key].push(null);
      }
      d.t.push(cols.t_s[i]);
      d.v.push(cols.voltage_V[i]);
      d.measured.push(cols.measured_mm[i]);
      d.predicted.push(cols.predicted_mm[i]);
      d.residual.push(cols.residual_mm[i]);
    }
    c.points += n;
    trim(c);
    c.dirty = true;
  }

  // Keeps the window's worth of message time (and at most MAX_POINTS).
  function trim(c) {
    const t = c.data.t;
    if (t.length === 0) return;
    const cutoff = t[t.length - 1] - windowS;
    let first = 0;
    while (first < t.length && t[first] < cutoff) first++;
    first = Math.max(first, t.length - MAX_POINTS);
    if (first > 0) for (const key of Object.keys(c.data)) c.data[key].splice(0, first);
    const r = c.reference;
    let kept = 0;
    while (kept < r.t.length && r.t[kept] < cutoff - REFERENCE_HOLD_S) kept++;
    kept = Math.max(kept, r.t.length - MAX_POINTS);
    if (kept > 0) {
      r.t.splice(0, kept);
      r.mm.splice(0, kept);
    }
  }

  function scheduleDraw() {
    if (drawQueued) return;
    drawQueued = true;
    requestAnimationFrame(draw);
  }

  function draw() {
    drawQueued = false;
    for (const c of cards.values()) {
      if (!c.dirty) continue;
      c.dirty = false;
      const d = c.data;
      c.plots.voltage.setData([d.t, d.v]);
      const reference = referenceAt(c);
      c.plots.deflection.setData([d.t, d.measured, d.predicted, reference]);
      c.plots.residual.setData([d.t, d.residual]);
      c.root.dataset.points = String(c.points);
      let measured = 0;
      for (const x of d.measured) if (x !== null) measured++;
      c.root.dataset.chartPoints = String(measured);
      c.root.dataset.referencePoints = String(reference.filter((x) => x !== null).length);
      c.counter.textContent = c.points.toLocaleString() + ' points';
    }
  }

  function resizeAll() {
    for (const c of cards.values())
      for (const key of Object.keys(c.plots)) {
        const width = Math.max(c.boxes[key].clientWidth, 200);
        if (c.plots[key].width !== width) c.plots[key].setSize({width, height: CHART_HEIGHT});
      }
  }

  // ---- readouts, model, alerts ------------------------------------------------------

  function setReadout(c, latest, received, samples, trialId, memberships) {
    if (received !== undefined) c.root.dataset.received = String(received);
    if (samples !== undefined) c.root.dataset.samples = String(samples);
    c.trial.textContent = trialId ? 'trial ' + trialId : 'no trial';
    if (!latest) return;
    const parts = [
      ['V', fmt(latest.voltage_V, 3) + ' V'],
      ['measured', fmt(latest.measured_mm, 4) + ' mm'],
    ];
    if (c.predicted) {
      parts.push(['predicted', fmt(latest.predicted_mm, 4) + ' mm']);
      parts.push(['residual', fmt(latest.residual_mm, 3) + ' mm']);
    }
    const r = c.reference;
    if (c.controlled && r.mm.length && r.mm[r.mm.length - 1] !== null)
      parts.push(['reference', fmt(r.mm[r.mm.length - 1], 4) + ' mm']);
    if (memberships && memberships.length > 1)
      parts.push(['rules', memberships.map((m) => fmt(m, 2)).join(' / ')]);
    c.readout.replaceChildren();
    for (const [name, value] of parts) {
      const item = el('span', 'reading');
      item.append(el('span', 'reading-name', name), el('span', 'reading-value', value));
      c.readout.append(item);
    }
    c.readout.append(el('span', 'reading-time', clock(latest.t_s)));
  }

  function lastOf(cols) {
    const n = cols.t_s.length;
    if (n === 0) return null;
    return {
      t_s: cols.t_s[n - 1],
      voltage_V: cols.voltage_V[n - 1],
      measured_mm: cols.measured_mm[n - 1],
      predicted_mm: cols.predicted_mm[n - 1],
      residual_mm: cols.residual_mm[n - 1],
    };
  }

  function showModel(c) {
    const m = c.modelInfo;
    const version = c.modelVersion;
    c.root.dataset.modelVersion = String(version);
    c.model.dataset.modelVersion = String(version);
    c.model.replaceChildren();
    if (!version) {
      c.model.append(el('span', 'model-none',
        'no model yet: measured voltage and deflection only; predictions start once a model is active'));
      return;
    }
    c.model.append(el('span', 'model-version', 'model v' + version));
    if (!m || m.version !== version) {
      c.model.append(el('span', 'model-detail', 'loading…'));
      return;
    }
    const bits = [];
    if (m.fit && m.fit.fit_percent !== undefined) bits.push('fit ' + fmt(m.fit.fit_percent, 4) + ' %');
    if (m.fit && m.fit.rmse_mm !== undefined) bits.push('RMSE ' + fmt(m.fit.rmse_mm, 3) + ' mm');
    if (m.kind === 'ts_fuzzy' && m.levels_V && m.levels_V.length)
      bits.push('T-S, ' + m.levels_V.length + ' rules at ' + m.levels_V.map((v) => fmt(v, 3)).join(', ') + ' V');
    else if (m.kind === 'tf') bits.push('one transfer function');
    if (m.trials && m.trials.length) bits.push('trials ' + m.trials.join(', '));
    for (const b of bits) c.model.append(el('span', 'model-detail', b));
  }

  // One model version: "v4 active · proposed from v3 · back relaxation (fraction 0.21 ±
  // 0.03, tau_s 31 ± 4) · held-out RMSE 0.085 → 0.021 mm, ×4.05 · trial 12".
  function versionItem(v) {
    const lineage = v.lineage || null;  // missing (flexidd before proposals): identified
    const li = el('li', 'version' + (v.active ? ' active' : '') + (lineage ? ' proposed' : ''));
    li.dataset.version = String(v.version);
    li.dataset.active = String(Boolean(v.active));
    li.dataset.kind = lineage ? 'proposed' : 'identified';
    li.append(el('span', 'version-number', 'v' + v.version));
    if (v.active) li.append(el('span', 'version-active', 'active'));
    const bits = [];
    if (lineage) {
      li.dataset.parent = String(lineage.parent_version);
      const by = lineage.proposed_by ? ' by ' + lineage.proposed_by : '';
      bits.push(lineage.parent_version > 0 ? 'proposed from v' + lineage.parent_version + by
        : 'proposed' + by + ' on a baseline identified on its trials');
      const effects = (lineage.effects || []).map((e) => {
        const params = Object.entries(e.params || {}).map(([name, p]) =>
          name + ' ' + fmt(p.value, 3) + (p.half_width_95 !== null && p.half_width_95 !== undefined ? ' ± ' + fmt(p.half_width_95, 2) : ''));
        return e.effect.replace(/_/g, ' ') + (params.length ? ' (' + params.join(', ') + ')' : '');
      });
      if (effects.length) bits.push(effects.join(' + '));
      if (lineage.heldout_rmse_before_mm !== null && lineage.heldout_rmse_after_mm !== null)
        bits.push('held-out RMSE ' + fmt(lineage.heldout_rmse_before_mm, 3) + ' → ' +
          fmt(lineage.heldout_rmse_after_mm, 3) + ' mm' +
          (lineage.heldout_gain !== null ? ', ×' + fmt(lineage.heldout_gain, 3) : ''));
      if (lineage.trials && lineage.trials.length)
        bits.push((lineage.trials.length > 1 ? 'trials ' : 'trial ') + lineage.trials.join(', '));
    } else {
      bits.push('identified');
      if (v.trials && v.trials.length) bits.push((v.trials.length > 1 ? 'trials ' : 'trial ') + v.trials.join(', '));
      if (v.fit && v.fit.fit_percent !== null) bits.push('fit ' + fmt(v.fit.fit_percent, 4) + ' %');
    }
    bits.forEach((b, i) => li.append(el('span', i === 0 ? 'version-detail version-origin' : 'version-detail', b)));
    return li;
  }

  function showVersions(c, versions, total, problem) {
    const box = c.versions;
    box.replaceChildren();
    if (!Array.isArray(versions)) {
      box.dataset.loaded = 'false';
      box.append(el('span', 'versions-none', 'model versions: ' + (problem || 'asking flexidd…')));
      return;
    }
    box.dataset.loaded = 'true';
    if (versions.length === 0) {
      box.append(el('span', 'versions-none', 'model versions: none stored yet'));
      return;
    }
    box.append(el('div', 'versions-head', 'Model versions'));
    const list = el('ol', 'version-list');
    for (const v of versions.slice(0, MAX_VERSIONS)) list.append(versionItem(v));
    box.append(list);
    const older = (total || versions.length) - Math.min(versions.length, MAX_VERSIONS);
    if (older > 0) box.append(el('div', 'versions-more', older + ' older (flexid models list --actuator ' + c.id + ')'));
  }

  function alertItem(a, withActuator) {
    const li = el('li', 'alert sev-' + a.severity);
    li.dataset.kind = a.kind;
    li.dataset.severity = a.severity;
    li.dataset.actuator = a.actuator;
    li.dataset.utime = String(a.utime);
    const head = el('div', 'alert-head');
    head.append(el('span', 'alert-kind', a.kind.replace(/_/g, ' ')));
    head.append(el('span', 'alert-severity', a.severity));
    if (withActuator && a.actuator) head.append(el('span', 'alert-actuator', a.actuator));
    const time = el('time', 'alert-time', clock(a.t_s));
    time.title = 'message time';
    head.append(time);
    li.append(head, el('p', 'alert-text', a.text));
    return li;
  }

  // Newest first, by message time.
  function insertAlert(list, item) {
    const utime = Number(item.dataset.utime);
    const before = [...list.children].find((n) => n.dataset.utime !== undefined && Number(n.dataset.utime) < utime);
    list.insertBefore(item, before || null);
    while (list.querySelectorAll('.alert').length > MAX_ALERTS) list.lastElementChild.remove();
  }

  function addAlert(a, live) {
    const key = [a.utime, a.actuator, a.kind, a.text].join('|');
    if (alertKeys.has(key)) return;
    alertKeys.add(key);
    const global = alertItem(a, true);
    if (live) global.classList.add('fresh');
    insertAlert($('alerts'), global);
    $('alert-count').textContent = String($('alerts').querySelectorAll('.alert').length);
    if (a.actuator) {
      const c = card(a.actuator);
      c.none.hidden = true;
      const local = alertItem(a, false);
      if (live) local.classList.add('fresh');
      insertAlert(c.alerts, local);
    }
  }

  function showCounters(counters) {
    if (!counters) return;
    $('stats').textContent =
      'samples ' + (counters.samples || 0).toLocaleString() +
      ' · predictions ' + counters.predictions.toLocaleString() +
      ' · alerts ' + counters.alerts.toLocaleString() +
      ' · bad messages ' + counters.bad_messages.toLocaleString() +
      (counters.out_of_order ? ' · out of order ' + counters.out_of_order.toLocaleString() : '') +
      (counters.bad_replies ? ' · bad replies from flexidd ' + counters.bad_replies.toLocaleString() : '');
  }

  // The flexidd that records an actuator, on its card (when it has one yet).
  function showDaemon(id, daemonId) {
    if (!daemonId) return;
    daemons.set(id, daemonId);
    const c = cards.get(id);
    if (!c) return;
    c.root.dataset.daemon = daemonId;
    c.daemon.textContent = 'flexidd ' + daemonId;
  }

  // ---- the stream ---------------------------------------------------------------------

  function applyState(state) {
    $('bus').textContent = 'bus: ' + state.lcm_url;
    $('version').textContent = 'flexid ' + state.version;
    const ids = new Set(state.actuators.map((a) => a.id));
    for (const [id, c] of cards) {
      if (!ids.has(id)) {
        c.root.remove();
        cards.delete(id);
      }
    }
    for (const a of state.actuators) {
      const c = card(a.id);
      clearData(c);
      c.points = 0;
      appendColumns(c, a.history);
      appendReference(c, a.reference);
      trim(c);
      notePredicted(c, a.history, a.model_version);
      c.modelVersion = a.model_version;
      c.modelInfo = a.model;
      showModel(c);
      showVersions(c, a.versions, a.versions_total, a.versions_problem);
      showDaemon(a.id, a.daemon);
      setReadout(c, a.latest, a.received, a.samples, a.trial, a.memberships);
      c.alerts.querySelectorAll('.alert').forEach((n) => n.remove());
      c.none.hidden = false;
    }
    $('alerts').replaceChildren();
    alertKeys.clear();
    for (const a of state.alerts.slice().reverse()) addAlert(a, false);
    $('alert-count').textContent = String($('alerts').querySelectorAll('.alert').length);
    $('empty').hidden = cards.size > 0;
    showCounters(state.counters);
    $('stats').title = state.last_problem ? 'last problem: ' + state.last_problem : '';
    scheduleDraw();
  }

  function onPoints(batch) {
    for (const a of batch.actuators) {
      const c = card(a.id);
      if (a.reset) clearData(c);
      appendColumns(c, a);
      appendReference(c, a.reference);
      trim(c);
      notePredicted(c, a, a.model_version);
      setReadout(c, lastOf(a), a.received, a.samples, a.trial, a.memberships);
      if (a.model_version !== c.modelVersion) {
        c.modelVersion = a.model_version;
        showModel(c);
      }
    }
    showCounters(batch.counters);
    scheduleDraw();
  }

  function onModel(m) {
    const c = card(m.actuator);
    c.modelInfo = m;
    if (m.version > c.modelVersion) c.modelVersion = m.version;
    showModel(c);
  }

  function setConnection(state, text) {
    const node = $('connection');
    node.dataset.state = state;
    node.textContent = text || state;
  }

  function reconnect(delayMs) {
    if (source) {
      source.close();
      source = null;
    }
    setConnection('reconnecting', 'reconnecting…');
    clearTimeout(retryTimer);
    retryTimer = setTimeout(connect, delayMs);
    retryMs = Math.min(retryMs * 2, 10000);
  }

  function connect() {
    setConnection('connecting', 'connecting…');
    fetch('/api/state', {cache: 'no-store'})
      .then((response) => {
        if (!response.ok) throw new Error('state: HTTP ' + response.status);
        return response.json();
      })
      .then((state) => {
        applyState(state);
        source = new EventSource('/events?after=' + state.event_id);
        source.addEventListener('open', () => {
          retryMs = 1000;
          setConnection('live', 'live');
        });
        source.addEventListener('points', (e) => onPoints(JSON.parse(e.data)));
        source.addEventListener('alert', (e) => addAlert(JSON.parse(e.data), true));
        source.addEventListener('model', (e) => onModel(JSON.parse(e.data)));
        source.addEventListener('versions', (e) => {
          const v = JSON.parse(e.data);
          showVersions(card(v.actuator), v.versions, v.total, v.problem);
        });
        source.addEventListener('daemon', (e) => {
          const d = JSON.parse(e.data);
          showDaemon(d.actuator, d.daemon);
        });
        source.addEventListener('resync', () => reconnect(0));
        source.onerror = () => reconnect(retryMs);
      })
      .catch(() => reconnect(retryMs));
  }

  function start() {
    const select = $('window');
    const asked = Number(new URLSearchParams(location.search).get('window_s'));
    if (asked > 0) {
      windowS = asked;
      if (![...select.options].some((o) => Number(o.value) === asked)) {
        const option = el('option', '', asked + ' s');
        option.value = String(asked);
        select.append(option);
      }
    }
    select.value = String(windowS);
    select.addEventListener('change', () => {
      windowS = Number(select.value);
      reconnect(0);  // the snapshot holds more history than a shorter window kept
    });
    window.addEventListener('resize', resizeAll);
    if (window.ResizeObserver) new ResizeObserver(resizeAll).observe($('actuators'));
    connect();
  }

  start();
})();
