// The gonio daemon's live status page. Hand-written, no framework, no build step: everything it shows comes
// from the daemon's JSON API (/api/campaigns, /api/campaigns/{id}/points.csv) and its server-sent event stream
// (/api/events), read with fetch so that a token can travel as an Authorization header (EventSource cannot
// send one). All text from the daemon goes into the page as textContent, never as HTML.
'use strict';

(() => {
  const TOKEN_KEY = 'gonio-token';
  const READINGS_SHOWN = 12;
  const LOG_SHOWN = 40;
  // Safety net when the event stream is down: the campaign list is fetched again this often.
  const POLL_MS = 10000;
  const RECONNECT_MIN_MS = 500;
  const RECONNECT_MAX_MS = 10000;
  const ABORT_ARM_MS = 4000;
  const RENDER_INTERVAL_MS = 200;
  const ON_INSTRUMENT = ['running', 'pausing', 'waiting-operator'];
  const FINAL = ['completed', 'aborted', 'failed'];
  const SVG_NS = 'http://www.w3.org/2000/svg';
  // Angles within this of the plane count as in-plane (degrees).
  const IN_PLANE_TOLERANCE_DEG = 0.5;
  const SERIES_CLASSES = 8;
  // Largest to smallest BRDF beyond which the in-plane plot starts in log scale (linear would hide the small
  // values at the centre); the log scale shows LOG_SCALE_DECADES decades below the top of the scale.
  const LOG_SCALE_RANGE = 20;
  const LOG_SCALE_DECADES = 3;

  const $ = (id) => document.getElementById(id);

  const page = {
    token: null,
    campaigns: new Map(), // id -> the API's campaign view, updated by events
    messages: new Map(), // id -> the message of the last state event
    currentId: null,
    follow: true,
    pointsFor: null, // the campaign whose points `points` holds
    points: new Map(), // point index -> point
    latestIndex: null,
    sseEvents: 0,
    pointsLoads: 0, // points.csv fetches answered
    plotMode: 'auto', // 'auto' | 'in-plane' | 'hemisphere'
    logScale: null, // null: chosen from the data (log when the values span more than LOG_SCALE_RANGE)
    abortArmed: null, // timer while the abort button waits for its second click
    renderQueued: false,
    lastRender: 0,
    tokenWaiters: [],
    // Per campaign, how many events changed its view: an API answer fetched before the latest event is older
    // than what the page shows and must not overwrite it (answers and events travel on different connections).
    changes: new Map(),
    refreshSent: 0,
    refreshApplied: 0,
    refreshTimer: null,
  };

  // ---------------------------------------------------------------------------------------------------------
  // Token: taken once from the URL fragment (never sent to the server), kept for this tab only.

  function takeTokenFromUrl() {
    const match = /(?:^#|&)token=([^&]*)/.exec(location.hash);
    if (match) {
      try {
        sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(match[1]));
      } catch (_) {
        sessionStorage.setItem(TOKEN_KEY, match[1]);
      }
      // Out of the address bar and the history entry.
      history.replaceState(null, '', location.pathname + location.search);
    }
    page.token = sessionStorage.getItem(TOKEN_KEY);
  }

  function needToken() {
    setConnection('token', 'token required');
    $('token-panel').hidden = false;
  }

  function waitForToken() {
    return new Promise((resolve) => page.tokenWaiters.push(resolve));
  }

  function onTokenForm(event) {
    event.preventDefault();
    const value = $('token-input').value.trim();
    if (!value) return;
    sessionStorage.setItem(TOKEN_KEY, value);
    page.token = value;
    $('token-input').value = '';
    $('token-panel').hidden = true;
    const waiters = page.tokenWaiters.splice(0);
    waiters.forEach((resolve) => resolve());
  }

  // ---------------------------------------------------------------------------------------------------------
  // The API.

  class ApiError extends Error {
    constructor(status, message) {
      super(message);
      this.status = status;
    }
  }

  async function api(path, options = {}) {
    const headers = {};
    if (page.token) headers.Authorization = 'Bearer ' + page.token;
    if (options.json !== undefined) headers['Content-Type'] = 'application/json';
    let response;
    try {
      response = await fetch(path, {
        method: options.method || 'GET',
        headers,
        body: options.json === undefined ? undefined : JSON.stringify(options.json),
        cache: 'no-store',
        signal: options.signal,
      });
    } catch (e) {
      throw new ApiError(0, 'cannot reach the daemon: ' + e.message);
    }
    if (response.status === 401) {
      needToken();
      throw new ApiError(401, 'the daemon needs a token');
    }
    if (!response.ok) {
      let message = response.status + ' ' + response.statusText;
      try {
        const body = await response.json();
        if (body && typeof body.error === 'string') message = body.error;
      } catch (_) {
        // Not JSON: keep the status line.
      }
      throw new ApiError(response.status, message);
    }
    return response;
  }

  async function refreshCampaigns() {
    const sent = ++page.refreshSent;
    const before = new Map(page.changes);
    const list = await (await api('/api/campaigns')).json();
    // A later request has already been answered: this answer is older.
    if (!Array.isArray(list) || sent < page.refreshApplied) return;
    page.refreshApplied = sent;
    for (const view of list) storeView(view, before);
    chooseCurrent();
    queueRender();
  }

  // Keep `view` unless events changed the campaign since `before` was taken; then ask again shortly.
  function storeView(view, before) {
    if ((page.changes.get(view.id) || 0) !== (before.get(view.id) || 0)) {
      refreshSoon();
      return;
    }
    page.campaigns.set(view.id, view);
  }

  function refreshSoon() {
    if (page.refreshTimer !== null) return;
    page.refreshTimer = setTimeout(() => {
      page.refreshTimer = null;
      refreshCampaigns().catch((e) => log('warn', e.message));
    }, 200);
  }

  function changed(id) {
    page.changes.set(id, (page.changes.get(id) || 0) + 1);
  }

  // The campaign shown: the one picked in the list, else the one on the instrument, else the next queued,
  // else the latest.
  function chooseCurrent() {
    const all = [...page.campaigns.values()].sort((a, b) => a.id - b.id);
    if (all.length === 0) return;
    let pick = null;
    if (!page.follow && page.campaigns.has(page.currentId)) {
      pick = page.currentId;
    } else {
      const on = all.find((c) => ON_INSTRUMENT.includes(c.state));
      const paused = all.find((c) => c.state === 'paused');
      const queued = all.find((c) => c.state === 'queued');
      pick = (on || paused || queued || all[all.length - 1]).id;
    }
    selectCampaign(pick);
  }

  function selectCampaign(id) {
    if (page.currentId === id && page.pointsFor === id) return;
    page.currentId = id;
    page.pointsFor = id;
    page.points = new Map();
    page.latestIndex = null;
    disarmAbort();
    queueRender();
    loadPoints(id).catch((e) => log('warn', 'cannot load the points of campaign ' + id + ': ' + e.message));
  }

  // The points already stored, from the CSV export; events add the ones that follow. `final`: the campaign has
  // completed, and its completion (values normalised again between references and corrected to the nominal
  // geometry, budgets completed) replaces what the events said; body[data-final-points] names it once drawn.
  async function loadPoints(id, final = false) {
    let text;
    try {
      text = await (await api('/api/campaigns/' + id + '/points.csv')).text();
    } finally {
      // Every answered fetch counted, drawn or not: the next render marks it drawn (`drawnLoads`), so that a
      // reader of the page (tests/browser) can tell points from a fetch from points from the event stream.
      page.pointsLoads += 1;
    }
    if (page.pointsFor !== id) return;
    for (const point of parsePointsCsv(text)) {
      if (final || !page.points.has(point.index)) page.points.set(point.index, point);
    }
    if (page.latestIndex === null && page.points.size > 0) page.latestIndex = largest(page.points.keys());
    queueRender();
    if (final) document.body.dataset.finalPoints = String(id);
  }

  function parsePointsCsv(text) {
    const lines = text.split(/\r?\n/).filter((l) => l.length > 0);
    if (lines.length === 0) return [];
    const header = lines[0].split(',');
    const column = (name) => header.indexOf(name);
    const num = (cells, name) => {
      const i = column(name);
      if (i < 0 || i >= cells.length || cells[i] === '') return null;
      const v = Number(cells[i]);
      return Number.isFinite(v) ? v : null;
    };
    const points = [];
    for (const line of lines.slice(1)) {
      const cells = line.split(',');
      const index = num(cells, 'index');
      if (index === null) continue;
      const flagsAt = column('flags');
      const flags = flagsAt >= 0 && cells[flagsAt] ? cells[flagsAt].split(';').filter((f) => f) : [];
      points.push({
        index,
        band_nm: num(cells, 'band_nm'),
        theta_i_deg: num(cells, 'theta_i_deg'),
        phi_i_deg: num(cells, 'phi_i_deg'),
        theta_o_deg: num(cells, 'theta_o_deg'),
        phi_o_deg: num(cells, 'phi_o_deg'),
        signal_w: num(cells, 'signal_w'),
        brdf_sr: num(cells, 'brdf_sr'),
        brdf_u_sr: num(cells, 'brdf_u_sr'),
        flags,
        t_s: num(cells, 't_s'),
      });
    }
    return points;
  }

  // ---------------------------------------------------------------------------------------------------------
  // Server-sent events over fetch (the format of the HTML standard: fields per line, events end at a blank
  // line, comments start with ':').

  class SseParser {
    constructor(onEvent) {
      this.onEvent = onEvent;
      this.buffer = '';
      this.data = [];
      this.type = '';
    }

    push(chunk) {
      this.buffer += chunk;
      for (;;) {
        const end = this.buffer.search(/\r\n|\n|\r/);
        if (end < 0) return;
        // A '\r' at the very end may be the first half of '\r\n': wait for the next chunk.
        if (this.buffer[end] === '\r' && end === this.buffer.length - 1) return;
        const width = this.buffer.startsWith('\r\n', end) ? 2 : 1;
        const line = this.buffer.slice(0, end);
        this.buffer = this.buffer.slice(end + width);
        this.line(line);
      }
    }

    line(line) {
      if (line === '') {
        if (this.data.length > 0) this.onEvent(this.type || 'message', this.data.join('\n'));
        this.data = [];
        this.type = '';
        return;
      }
      if (line.startsWith(':')) return;
      const colon = line.indexOf(':');
      const field = colon < 0 ? line : line.slice(0, colon);
      let value = colon < 0 ? '' : line.slice(colon + 1);
      if (value.startsWith(' ')) value = value.slice(1);
      if (field === 'data') this.data.push(value);
      else if (field === 'event') this.type = value;
    }
  }

  async function streamEvents() {
    let delay = RECONNECT_MIN_MS;
    for (;;) {
      try {
        const response = await api('/api/events');
        setConnection('live', 'live');
        delay = RECONNECT_MIN_MS;
        // Whatever happened while not listening: fetch the state again (events carry only changes).
        resync();
        const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
        const parser = new SseParser(onServerEvent);
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          parser.push(value);
        }
        setConnection('reconnecting', 'the event stream ended');
      } catch (e) {
        if (e instanceof ApiError && e.status === 401) {
          await waitForToken();
          continue;
        }
        setConnection('reconnecting', e.message);
      }
      await new Promise((resolve) => setTimeout(resolve, delay));
      delay = Math.min(delay * 2, RECONNECT_MAX_MS);
    }
  }

  function resync() {
    const id = page.currentId;
    refreshCampaigns()
      .then(() => {
        // Points may have been committed while the stream was down.
        if (id !== null && id === page.currentId) return loadPoints(id);
        return undefined;
      })
      .catch((e) => log('warn', e.message));
  }

  function onServerEvent(type, text) {
    page.sseEvents += 1;
    document.body.dataset.sseEvents = String(page.sseEvents);
    let event;
    try {
      event = JSON.parse(text);
    } catch (_) {
      log('warn', 'unreadable event of type ' + type);
      return;
    }
    const campaign = page.campaigns.get(event.campaign);
    switch (event.type) {
      case 'state': {
        changed(event.campaign);
        page.messages.set(event.campaign, event.message || null);
        if (campaign) {
          campaign.state = event.state;
          campaign.operator_message = event.state === 'waiting-operator' ? event.message || null : null;
          if (!ON_INSTRUMENT.includes(event.state)) campaign.eta_s = null;
        }
        log(
          event.state === 'failed' ? 'fault' : '',
          'campaign ' + event.campaign + ': ' + event.state + (event.message ? ' (' + event.message + ')' : ''),
        );
        if (page.follow && ON_INSTRUMENT.includes(event.state) && event.campaign !== page.currentId) {
          selectCampaign(event.campaign);
        }
        if (event.state === 'completed' && event.campaign === page.pointsFor) {
          loadPoints(event.campaign, true).catch((e) => log('warn', 'cannot read the completed points: ' + e.message));
        }
        // The view holds more than the event (last error, ETA): fetch it.
        refreshSoon();
        break;
      }
      case 'point': {
        if (event.campaign === page.pointsFor && event.point && typeof event.point.index === 'number') {
          page.points.set(event.point.index, event.point);
          page.latestIndex = event.point.index;
        }
        break;
      }
      case 'progress': {
        changed(event.campaign);
        if (campaign) {
          campaign.points_done = event.done;
          campaign.total_points = event.total;
          campaign.eta_s = event.eta_s;
        } else {
          refreshSoon();
        }
        break;
      }
      case 'fault':
        log('fault', 'campaign ' + event.campaign + ': ' + event.message);
        break;
      case 'lagged':
        log('warn', 'missed ' + event.missed + ' events: reloading');
        resync();
        break;
      default:
        break;
    }
    queueRender();
  }

  // ---------------------------------------------------------------------------------------------------------
  // Buttons.

  // The report is fetched with the token (a plain link could not carry it) and saved as a file: it is a
  // self-contained page the lab keeps, not a view of the daemon.
  async function downloadReport(id) {
    status('writing the report of campaign ' + id + ' (the models are fitted: a few seconds)');
    try {
      const blob = await (await api('/api/campaigns/' + id + '/report.html')).blob();
      const c = page.campaigns.get(id);
      const link = document.createElement('a');
      link.href = URL.createObjectURL(blob);
      link.download = (c ? c.name : 'campaign') + '-' + id + '-report.html';
      link.id = 'report-download';
      link.hidden = true;
      document.body.appendChild(link);
      link.click();
      setTimeout(() => {
        URL.revokeObjectURL(link.href);
        link.remove();
      }, 60000);
      status('report of campaign ' + id + ' saved as ' + link.download);
      log('', 'report of campaign ' + id + ' downloaded (' + blob.size + ' bytes)');
    } catch (e) {
      status('cannot write the report: ' + e.message, true);
      log('warn', 'cannot write the report of campaign ' + id + ': ' + e.message);
    }
  }

  async function act(action) {
    const id = page.currentId;
    if (id === null) return;
    if (action === 'abort' && page.abortArmed === null) {
      // Two clicks: an abort cannot be undone.
      const button = $('btn-abort');
      button.textContent = 'Really abort?';
      button.classList.add('armed');
      page.abortArmed = setTimeout(disarmAbort, ABORT_ARM_MS);
      return;
    }
    disarmAbort();
    status('');
    if (action === 'report') {
      await downloadReport(id);
      return;
    }
    try {
      const before = new Map(page.changes);
      const view = await (await api('/api/campaigns/' + id + '/' + action, { method: 'POST' })).json();
      if (view && view.id === id) storeView(view, before);
      status(action + ' requested for campaign ' + id);
      log('', action + ' requested for campaign ' + id);
    } catch (e) {
      status('cannot ' + action + ': ' + e.message, true);
      log('warn', 'cannot ' + action + ' campaign ' + id + ': ' + e.message);
    }
    queueRender();
  }

  function disarmAbort() {
    if (page.abortArmed !== null) clearTimeout(page.abortArmed);
    page.abortArmed = null;
    const button = $('btn-abort');
    button.textContent = 'Abort';
    button.classList.remove('armed');
  }

  function status(text, isError = false) {
    const el = $('action-status');
    el.textContent = text;
    el.classList.toggle('error', isError);
  }

  // ---------------------------------------------------------------------------------------------------------
  // Rendering (batched: many events may arrive at once).

  function queueRender() {
    if (page.renderQueued) return;
    page.renderQueued = true;
    // At most a few redraws a second: the plot is redrawn whole, and a campaign may have thousands of points.
    const wait = Math.max(0, page.lastRender + RENDER_INTERVAL_MS - Date.now());
    setTimeout(() => {
      page.renderQueued = false;
      page.lastRender = Date.now();
      renderCampaign();
      renderCampaignList();
      renderReadings();
      renderPlot();
      // What the drawing shows: the points.csv fetches answered and the events received when it was drawn (a
      // reader of the page, tests/browser, counts the plot's growth against these, not against events that
      // arrived while a redraw was held back).
      document.body.dataset.drawnLoads = String(page.pointsLoads);
      document.body.dataset.drawnEvents = String(page.sseEvents);
    }, wait);
  }

  function setConnection(state, text) {
    const el = $('connection');
    el.dataset.state = state;
    el.textContent = text;
  }

  function log(kind, text) {
    const list = $('log');
    const item = document.createElement('li');
    if (kind) item.className = kind;
    const time = document.createElement('span');
    time.className = 'time';
    time.textContent = new Date().toLocaleTimeString();
    item.append(time, document.createTextNode(text));
    list.prepend(item);
    while (list.children.length > LOG_SHOWN) list.lastElementChild.remove();
  }

  function formatDuration(seconds) {
    if (typeof seconds !== 'number' || !Number.isFinite(seconds) || seconds < 0) return null;
    const s = Math.round(seconds);
    if (s < 60) return s + ' s';
    if (s < 3600) return Math.floor(s / 60) + ' min ' + String(s % 60).padStart(2, '0') + ' s';
    return Math.floor(s / 3600) + ' h ' + String(Math.floor((s % 3600) / 60)).padStart(2, '0') + ' min';
  }

  function renderCampaign() {
    const c = page.campaigns.get(page.currentId);
    const stateEl = $('c-state');
    if (!c) {
      for (const b of document.querySelectorAll('#campaign .buttons button')) b.disabled = true;
      return;
    }
    $('c-name').textContent = c.name;
    stateEl.textContent = c.state;
    stateEl.dataset.state = c.state;
    const created = new Date(c.created_unix_s * 1000);
    $('c-meta').textContent =
      'campaign ' + c.id + (c.dry_run ? ' · dry-run' : '') + ' · submitted ' + created.toLocaleString() +
      ' · ' + c.software_version;

    // The daemon keeps the last error (or pause reason) after a resume: show it only while it explains the
    // state.
    let message = null;
    if (c.state === 'waiting-operator') message = 'Operator: ' + (c.operator_message || page.messages.get(c.id) || '');
    else if (['paused', 'pausing'].includes(c.state)) message = page.messages.get(c.id) || c.last_error || null;
    $('c-message').hidden = !message;
    $('c-message').textContent = message || '';
    const error = ['failed', 'aborted'].includes(c.state) ? c.last_error : null;
    $('c-error').hidden = !error;
    $('c-error').textContent = error || '';

    const total = c.total_points > 0 ? c.total_points : 1;
    const progress = $('c-progress');
    progress.max = total;
    progress.value = Math.min(c.points_done, total);
    $('c-points').textContent = c.points_done + ' / ' + c.total_points + ' points';
    const eta = formatDuration(c.eta_s);
    let etaText = '';
    if (eta && !FINAL.includes(c.state)) {
      etaText = 'ETA ' + eta + (c.dry_run ? ' of simulated instrument time' : '');
      if (!c.dry_run) {
        const end = new Date(Date.now() + c.eta_s * 1000);
        etaText += ' (about ' + end.toLocaleTimeString([], { hour: '2-digit', minute: '2-digit' }) + ')';
      }
    }
    $('c-eta').textContent = etaText;

    const allowed = {
      pause: ['queued', 'running', 'waiting-operator'].includes(c.state),
      resume: ['pausing', 'paused'].includes(c.state),
      confirm: c.state === 'waiting-operator',
      abort: !FINAL.includes(c.state),
      report: c.points_done > 0,
    };
    for (const [action, ok] of Object.entries(allowed)) $('btn-' + action).disabled = !ok;
    if (!allowed.abort) disarmAbort();
  }

  function renderCampaignList() {
    const body = document.querySelector('#campaigns tbody');
    const rows = [...page.campaigns.values()].sort((a, b) => b.id - a.id);
    body.replaceChildren(
      ...rows.map((c) => {
        const tr = document.createElement('tr');
        tr.dataset.id = String(c.id);
        if (c.id === page.currentId) tr.className = 'selected';
        for (const text of [String(c.id), c.name, c.state, c.points_done + '/' + c.total_points]) {
          const td = document.createElement('td');
          td.textContent = text;
          tr.append(td);
        }
        return tr;
      }),
    );
  }

  // Math.max(...xs) fails beyond some hundred thousand arguments: a campaign can have that many points.
  function largest(xs) {
    let m = -Infinity;
    for (const x of xs) if (x > m) m = x;
    return m;
  }

  function smallest(xs) {
    let m = Infinity;
    for (const x of xs) if (x < m) m = x;
    return m;
  }

  function fixed(v, digits) {
    if (typeof v !== 'number' || !Number.isFinite(v)) return '—';
    // No "-0.00" for a value that rounds to zero.
    return (Math.abs(v) < 0.5 * Math.pow(10, -digits) ? 0 : v).toFixed(digits);
  }

  function sci(v, digits) {
    return typeof v === 'number' && Number.isFinite(v) ? v.toExponential(digits) : '—';
  }

  function renderReadings() {
    const body = document.querySelector('#readings tbody');
    const latest = [...page.points.values()].sort((a, b) => b.index - a.index).slice(0, READINGS_SHOWN);
    $('readings-empty').hidden = latest.length > 0;
    body.replaceChildren(
      ...latest.map((p) => {
        const tr = document.createElement('tr');
        tr.dataset.index = String(p.index);
        const flags = Array.isArray(p.flags) ? p.flags.join(', ') : '';
        const cells = [
          String(p.index),
          fixed(p.band_nm, 1),
          fixed(p.theta_i_deg, 2),
          fixed(p.phi_i_deg, 2),
          fixed(p.theta_o_deg, 2),
          fixed(p.phi_o_deg, 2),
          sci(p.signal_w, 4),
          sci(p.brdf_sr, 4),
          sci(p.brdf_u_sr, 2),
          flags,
          fixed(p.t_s, 1),
        ];
        cells.forEach((text, i) => {
          const td = document.createElement('td');
          td.textContent = text;
          if (i === 7 && p.brdf_sr === null) td.className = 'invalid';
          tr.append(td);
        });
        return tr;
      }),
    );
  }

  // ---------------------------------------------------------------------------------------------------------
  // The polar plot (SVG, one circle per point).
  // In-plane data: the classic goniometric plot, signed theta_o as the angle from the normal (up; positive on
  // the specular side, to the right), the BRDF as the radius, one curve per incidence and band.
  // Other data: the outgoing hemisphere seen from above, theta_o as the radius, phi_o as the angle, the BRDF
  // as the colour (log scale).

  function svg(name, attributes = {}, parent = null) {
    const el = document.createElementNS(SVG_NS, name);
    for (const [k, v] of Object.entries(attributes)) el.setAttribute(k, String(v));
    if (parent) parent.append(el);
    return el;
  }

  function wrapDeg(angle) {
    return ((angle % 360) + 360) % 360;
  }

  // Signed theta_o of an in-plane point, or null when the point is out of the incidence plane.
  function signedThetaO(p) {
    if (p.theta_o_deg < 1e-6) return 0;
    const delta = wrapDeg(p.phi_o_deg - p.phi_i_deg);
    if (Math.abs(delta - 180) <= IN_PLANE_TOLERANCE_DEG) return p.theta_o_deg;
    if (delta <= IN_PLANE_TOLERANCE_DEG || delta >= 360 - IN_PLANE_TOLERANCE_DEG) return -p.theta_o_deg;
    return null;
  }

  function niceCeil(v) {
    if (!(v > 0)) return 1;
    const power = Math.pow(10, Math.floor(Math.log10(v)));
    for (const m of [1, 2, 2.5, 5, 10]) if (m * power >= v * (1 - 1e-12)) return m * power;
    return 10 * power;
  }

  function seriesKey(p) {
    return fixed(p.theta_i_deg, 2) + '|' + fixed(p.band_nm, 1);
  }

  function renderPlot() {
    const plot = $('polar');
    const points = [...page.points.values()]
      .filter((p) => [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg].every(Number.isFinite))
      .sort((a, b) => a.index - b.index);
    const inPlaneData = points.every((p) => signedThetaO(p) !== null);
    const mode = page.plotMode === 'auto' ? (inPlaneData ? 'in-plane' : 'hemisphere') : page.plotMode;
    $('plot-mode').textContent = mode === 'in-plane' ? 'hemisphere view' : 'in-plane view';
    $('plot-mode').dataset.mode = mode;
    const values = points.map((p) => p.brdf_sr).filter((v) => typeof v === 'number' && v > 0);
    const max = niceCeil(values.length ? largest(values) : 1);
    const wide = values.length > 0 && largest(values) > LOG_SCALE_RANGE * smallest(values);
    const logScale = page.logScale === null ? wide : page.logScale;
    $('plot-scale').textContent = logScale ? 'linear scale' : 'log scale';
    $('plot-scale').dataset.log = String(logScale);
    $('plot-scale').hidden = mode !== 'in-plane';
    plot.dataset.mode = mode;
    plot.dataset.scale = logScale ? 'log' : 'linear';
    plot.dataset.max = String(max);
    plot.replaceChildren();
    if (mode === 'in-plane') drawInPlane(plot, points, max, logScale);
    else drawHemisphere(plot, points, values);
    if (points.length === 0) {
      svg('text', { class: 'empty', x: 0, y: mode === 'in-plane' ? -40 : 0 }, plot).textContent =
        'points appear here as they are measured';
    }
  }

  function drawInPlane(plot, points, max, logScale) {
    plot.setAttribute('viewBox', '-120 -112 240 130');
    const R = 100;
    const logMin = Math.log10(max) - LOG_SCALE_DECADES;
    const radius = (v) => {
      if (!(typeof v === 'number' && v > 0)) return null;
      if (!logScale) return (R * Math.min(v, max)) / max;
      return (R * Math.min(1, Math.max(0, Math.log10(v) - logMin) / LOG_SCALE_DECADES));
    };
    const at = (r, signedDeg) => {
      const a = (signedDeg * Math.PI) / 180;
      return [r * Math.sin(a), -r * Math.cos(a)];
    };
    // Grid: four rings, spokes every 30 degrees.
    for (let k = 1; k <= 4; k += 1) {
      const r = (R * k) / 4;
      svg('path', { class: 'grid', d: `M ${-r} 0 A ${r} ${r} 0 0 1 ${r} 0` }, plot);
      const label = logScale ? Math.pow(10, logMin + (LOG_SCALE_DECADES * k) / 4) : (max * k) / 4;
      svg('text', { class: 'label', x: r, y: 5 }, plot).textContent = label.toPrecision(2);
    }
    for (let deg = -90; deg <= 90; deg += 30) {
      const [x, y] = at(R, deg);
      svg('line', { class: deg === 0 ? 'axis' : 'grid', x1: 0, y1: 0, x2: x, y2: y }, plot);
      const [lx, ly] = at(R + 7, deg);
      svg('text', { class: 'label', x: lx, y: ly }, plot).textContent = deg + '°';
    }
    svg('text', { class: 'label', x: 0, y: 11 }, plot).textContent =
      'BRDF (1/sr, ' + (logScale ? 'log' : 'linear') + ' scale) against signed θo';
    // Incidences: on the source's side (negative angles).
    const incidences = [...new Set(points.map((p) => p.theta_i_deg.toFixed(2)))];
    for (const t of incidences) {
      const [x, y] = at(R, -Number(t));
      svg('line', { class: 'incident', x1: 0, y1: 0, x2: x, y2: y }, plot);
    }
    const series = seriesOf(points);
    for (const [i, s] of series.entries()) {
      const cls = 's' + (i % SERIES_CLASSES);
      const ordered = s.points
        .map((p) => ({ p, a: signedThetaO(p), r: radius(p.brdf_sr) }))
        .filter((q) => q.a !== null)
        .sort((q1, q2) => q1.a - q2.a);
      const line = ordered.filter((q) => q.r !== null).map((q) => at(q.r, q.a).map((v) => v.toFixed(2)).join(','));
      if (line.length > 1) svg('polyline', { class: 'curve ' + cls, points: line.join(' ') }, plot);
      for (const q of ordered) {
        // An invalid point (no BRDF) sits on the rim, hollow.
        const [x, y] = at(q.r === null ? R : q.r, q.a);
        addPoint(plot, q.p, x, y, cls);
      }
    }
    legend(series, 'in-plane; dashed: incidence');
  }

  function drawHemisphere(plot, points, values) {
    plot.setAttribute('viewBox', '-120 -120 240 250');
    const R = 100;
    for (const t of [30, 60, 90]) {
      svg('circle', { class: t === 90 ? 'axis' : 'grid', cx: 0, cy: 0, r: (R * t) / 90 }, plot);
      svg('text', { class: 'label', x: (R * t) / 90 - 6, y: -3 }, plot).textContent = t + '°';
    }
    for (let phi = 0; phi < 360; phi += 45) {
      const a = (phi * Math.PI) / 180;
      svg('line', { class: 'grid', x1: 0, y1: 0, x2: R * Math.cos(a), y2: -R * Math.sin(a) }, plot);
      svg('text', { class: 'label', x: (R + 9) * Math.cos(a), y: -(R + 9) * Math.sin(a) }, plot).textContent =
        'φ ' + phi + '°';
    }
    const logs = values.map(Math.log10);
    const lo = logs.length ? smallest(logs) : 0;
    const hi = logs.length ? largest(logs) : 1;
    for (const p of points) {
      const r = (R * Math.min(p.theta_o_deg, 90)) / 90;
      const a = (p.phi_o_deg * Math.PI) / 180;
      const v = p.brdf_sr;
      const fill = typeof v === 'number' && v > 0 ? ramp(hi > lo ? (Math.log10(v) - lo) / (hi - lo) : 1) : null;
      addPoint(plot, p, r * Math.cos(a), -r * Math.sin(a), '', fill);
    }
    // The colour scale.
    const steps = 20;
    for (let k = 0; k < steps; k += 1) {
      svg('rect', { x: -60 + (120 * k) / steps, y: 114, width: 120 / steps + 0.2, height: 4, fill: ramp(k / (steps - 1)) }, plot);
    }
    svg('text', { class: 'label', x: -72, y: 116 }, plot).textContent = logs.length ? Math.pow(10, lo).toPrecision(2) : '';
    svg('text', { class: 'label', x: 72, y: 116 }, plot).textContent = logs.length ? Math.pow(10, hi).toPrecision(2) : '';
    svg('text', { class: 'label', x: 0, y: 124 }, plot).textContent = 'BRDF (1/sr), log scale';
    legend(seriesOf(points), 'outgoing hemisphere from above: radius θo, angle φo');
  }

  function addPoint(plot, p, x, y, cls, fill = null) {
    const valid = typeof p.brdf_sr === 'number';
    const classes = ['pt', cls];
    if (!valid) classes.push('invalid');
    if (p.index === page.latestIndex) classes.push('latest');
    const c = svg('circle', {
      class: classes.filter((k) => k).join(' '),
      cx: x.toFixed(2),
      cy: y.toFixed(2),
      r: p.index === page.latestIndex ? 2.6 : 1.8,
      'data-index': p.index,
    }, plot);
    if (fill) c.setAttribute('fill', fill);
    svg('title', {}, c).textContent =
      '#' + p.index + ': θi ' + fixed(p.theta_i_deg, 1) + '°, θo ' + fixed(p.theta_o_deg, 1) + '°, φo ' +
      fixed(p.phi_o_deg, 1) + '°, ' + fixed(p.band_nm, 0) + ' nm: ' +
      (valid ? sci(p.brdf_sr, 3) + ' 1/sr' : 'no value (' + (p.flags || []).join(', ') + ')');
  }

  function seriesOf(points) {
    const map = new Map();
    for (const p of points) {
      const key = seriesKey(p);
      if (!map.has(key)) map.set(key, { theta_i_deg: p.theta_i_deg, band_nm: p.band_nm, points: [] });
      map.get(key).points.push(p);
    }
    return [...map.values()].sort((a, b) => a.theta_i_deg - b.theta_i_deg || a.band_nm - b.band_nm);
  }

  function legend(series, note) {
    const el = $('plot-legend');
    el.replaceChildren();
    for (const [i, s] of series.entries()) {
      const span = document.createElement('span');
      span.className = 'series';
      const swatch = document.createElement('span');
      swatch.className = 'swatch s' + (i % SERIES_CLASSES);
      swatch.textContent = '●';
      span.append(swatch, 'θi ' + fixed(s.theta_i_deg, 1) + '°, ' + fixed(s.band_nm, 0) + ' nm (' + s.points.length + ')');
      el.append(span);
    }
    el.append(note);
  }

  // A perceptually ordered ramp (dark blue to yellow), linear between a few stops.
  const RAMP = [
    [68, 1, 84],
    [59, 82, 139],
    [33, 145, 140],
    [94, 201, 98],
    [253, 231, 37],
  ];

  function ramp(t) {
    const x = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
    const i = Math.min(RAMP.length - 2, Math.floor(x));
    const f = x - i;
    const rgb = RAMP[i].map((c, k) => Math.round(c + f * (RAMP[i + 1][k] - c)));
    return 'rgb(' + rgb.join(',') + ')';
  }

  // ---------------------------------------------------------------------------------------------------------
  // Start.

  function start() {
    takeTokenFromUrl();
    $('token-form').addEventListener('submit', onTokenForm);
    for (const button of document.querySelectorAll('#campaign .buttons button')) {
      button.addEventListener('click', () => act(button.dataset.action));
    }
    $('follow').addEventListener('change', (e) => {
      page.follow = e.target.checked;
      if (page.follow) chooseCurrent();
    });
    document.querySelector('#campaigns tbody').addEventListener('click', (e) => {
      const row = e.target.closest('tr');
      if (!row) return;
      page.follow = false;
      $('follow').checked = false;
      selectCampaign(Number(row.dataset.id));
    });
    $('plot-mode').addEventListener('click', () => {
      page.plotMode = $('plot-mode').dataset.mode === 'in-plane' ? 'hemisphere' : 'in-plane';
      queueRender();
    });
    $('plot-scale').addEventListener('click', () => {
      page.logScale = $('plot-scale').dataset.log !== 'true';
      queueRender();
    });
    setInterval(() => refreshCampaigns().catch(() => {}), POLL_MS);
    refreshCampaigns().catch((e) => log('warn', e.message));
    streamEvents();
  }

  // The console panel (console.js) shares the page's API access, event-stream parser and campaigns.
  window.gonio = {
    api,
    ApiError,
    SseParser,
    // The campaign that owns the instrument (running, pausing or waiting for its operator), or null.
    owner: () => [...page.campaigns.values()].find((c) => ON_INSTRUMENT.includes(c.state)) || null,
  };

  start();
})();
