// The console panel of the status page: the axes' positions, jog buttons, homing, the filter wheel, a live
// trace of the meter, and the emergency stop, through the daemon's /api/console routes. It uses the page's
// API access and event-stream parser (window.gonio, from status.js). The controls are disabled, with the
// reason, while a campaign owns the instrument; the emergency stop never is. Text from the daemon goes into the
// page as textContent, never as HTML.
'use strict';

(() => {
  const OWNER_CHECK_MS = 500;
  const TRACE_INTERVAL_MS = 250;
  const TRACE_POINTS = 120;
  const SVG_NS = 'http://www.w3.org/2000/svg';
  const $ = (id) => document.getElementById(id);
  const gonio = window.gonio;

  const panel = {
    state: null, // the last /api/console/state answer
    busy: false, // a console request is on its way
    owner: null, // the campaign that owns the instrument, or null
    trace: [], // the live trace's readings (oldest first)
    traceAbort: null, // AbortController of the reading stream while it runs
  };

  function say(text, isError = false) {
    const s = $('console-status');
    s.textContent = text;
    s.classList.toggle('error-text', isError);
  }

  function controls() {
    return [...document.querySelectorAll('#console-card .console-control')];
  }

  // Enabled only when the instrument is the console's to use and no request is on its way.
  function renderEnabled() {
    const reason = panel.owner
      ? 'Campaign ' + panel.owner.id + ' (' + panel.owner.name + ') is ' + panel.owner.state
        + ' on the instrument: the console waits (pause the campaign to use it).'
      : null;
    const note = $('console-reason');
    note.hidden = reason === null;
    note.textContent = reason || '';
    const off = reason !== null || panel.busy || panel.state === null;
    for (const c of controls()) c.disabled = off;
    $('console-card').dataset.enabled = String(!off);
  }

  function renderPositions(axes) {
    for (const a of axes) {
      const cell = document.querySelector('#console-axes tr[data-axis="' + CSS.escape(a.name) + '"] .pos');
      if (cell) cell.textContent = typeof a.position_deg === 'number' ? a.position_deg.toFixed(4) : '?';
    }
  }

  function renderState(state) {
    panel.state = state;
    const body = document.querySelector('#console-axes tbody');
    body.replaceChildren();
    for (const a of state.axes) {
      const row = document.createElement('tr');
      row.dataset.axis = a.name;
      const name = document.createElement('td');
      name.textContent = a.name;
      const pos = document.createElement('td');
      pos.className = 'pos';
      const flags = document.createElement('td');
      flags.className = 'muted';
      flags.textContent = [a.referenced === false ? 'not referenced' : '', a.fault || ''].filter(Boolean).join('; ');
      const jogCell = document.createElement('td');
      for (const sign of [-1, 1]) {
        const b = document.createElement('button');
        b.type = 'button';
        b.className = 'console-control jog';
        b.dataset.axis = a.name;
        b.dataset.sign = String(sign);
        b.textContent = sign < 0 ? '−' : '+';
        b.title = 'jog ' + a.name + (sign < 0 ? ' down' : ' up') + ' by the step';
        b.addEventListener('click', () => jog(a.name, sign));
        jogCell.append(b);
      }
      row.append(name, pos, jogCell, flags);
      body.append(row);
    }
    renderPositions(state.axes.filter((a) => a.position_deg !== null));
    const select = $('console-filter');
    select.replaceChildren();
    const wheel = state.wheel;
    for (const f of (wheel && wheel.filters) || []) {
      const o = document.createElement('option');
      o.value = String(f.position);
      o.textContent = f.position + (typeof f.band_nm === 'number' ? ' (' + f.band_nm + ' nm)' : ' (blank)');
      if (wheel.position === f.position) o.selected = true;
      select.append(o);
    }
    renderEnabled();
  }

  // One console request; the panel is disabled while it is on its way. Returns the answer, or null.
  async function request(path, json, what) {
    panel.busy = true;
    renderEnabled();
    try {
      const options = json === undefined ? {} : { method: 'POST', json };
      const answer = await (await gonio.api(path, options)).json();
      say(what);
      return answer;
    } catch (e) {
      say('cannot ' + what + ': ' + e.message, true);
      return null;
    } finally {
      panel.busy = false;
      renderEnabled();
    }
  }

  async function refreshState() {
    const state = await request('/api/console/state', undefined, 'read the instrument');
    if (state) renderState(state);
  }

  async function jog(axis, sign) {
    const step = Number($('jog-step').value);
    if (!(step > 0)) {
      say('the step must be a positive number of degrees', true);
      return;
    }
    const axes = await request('/api/console/jog', { axis, delta_deg: sign * step },
      'jog ' + axis + ' by ' + sign * step + ' deg');
    if (axes) renderPositions(axes);
  }

  async function homeAll() {
    const state = await request('/api/console/home', {}, 'home every axis');
    if (state) renderState(state);
  }

  async function turnWheel() {
    const position = $('console-filter').value;
    const answer = await request('/api/console/filter', { filter: position }, 'turn the wheel to ' + position);
    if (answer) $('console-card').dataset.wheel = String(answer.position);
  }

  async function estop() {
    try {
      await gonio.api('/api/estop', { method: 'POST' });
      say('emergency stop sent: the instrument is halted and queued campaigns are paused');
    } catch (e) {
      say('emergency stop failed: ' + e.message, true);
    }
  }

  // The live trace: the meter's readings from the daemon's reading stream, drawn as a line.
  function drawTrace() {
    const svg = $('trace');
    svg.replaceChildren();
    const values = panel.trace.map((r) => r.power_w);
    svg.dataset.points = String(values.length);
    if (values.length === 0) return;
    const hi = Math.max(...values);
    const lo = Math.min(...values);
    const span = hi > lo ? hi - lo : Math.abs(hi) || 1;
    const xy = values.map((v, i) => [
      (240 * i) / Math.max(TRACE_POINTS - 1, 1),
      75 - (70 * (v - lo)) / span,
    ]);
    const line = document.createElementNS(SVG_NS, 'polyline');
    line.setAttribute('points', xy.map((p) => p[0].toFixed(1) + ',' + p[1].toFixed(1)).join(' '));
    line.setAttribute('class', 'trace-line');
    svg.append(line);
    const last = panel.trace[panel.trace.length - 1];
    $('trace-value').textContent = last.power_w.toExponential(4) + ' W'
      + (typeof last.band_nm === 'number' ? ' at ' + last.band_nm + ' nm' : ' (no band filter)')
      + (last.overload ? ' OVERLOAD' : '');
  }

  function onReading(type, text) {
    let data;
    try {
      data = JSON.parse(text);
    } catch (_) {
      return;
    }
    if (type === 'reading') {
      panel.trace.push(data);
      if (panel.trace.length > TRACE_POINTS) panel.trace.shift();
      renderPositions(data.axes || []);
      drawTrace();
    } else if (type === 'unavailable') {
      $('trace-value').textContent = 'no reading: ' + data.error;
    }
  }

  async function toggleTrace() {
    const button = $('console-trace');
    if (panel.traceAbort) {
      panel.traceAbort.abort();
      panel.traceAbort = null;
      button.textContent = 'Start live trace';
      return;
    }
    const abort = new AbortController();
    panel.traceAbort = abort;
    button.textContent = 'Stop live trace';
    try {
      const response = await gonio.api('/api/console/readings?interval_ms=' + TRACE_INTERVAL_MS,
        { signal: abort.signal });
      const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
      const parser = new gonio.SseParser(onReading);
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        parser.push(value);
      }
    } catch (e) {
      if (e.name !== 'AbortError' && !abort.signal.aborted) say('live trace ended: ' + e.message, true);
    }
    if (panel.traceAbort === abort) {
      panel.traceAbort = null;
      button.textContent = 'Start live trace';
    }
  }

  function watchOwner() {
    const owner = gonio.owner();
    const changed = (owner && owner.id) !== (panel.owner && panel.owner.id)
      || (owner && owner.state) !== (panel.owner && panel.owner.state);
    panel.owner = owner;
    if (!changed) return;
    // A campaign took the instrument: the trace would only say so every time.
    if (owner !== null && panel.traceAbort) toggleTrace();
    renderEnabled();
    // The instrument came back to the console: read where everything is now.
    if (owner === null) refreshState();
  }

  function start() {
    if (!gonio) return;
    $('console-home').addEventListener('click', homeAll);
    $('console-filter').addEventListener('change', turnWheel);
    $('console-trace').addEventListener('click', toggleTrace);
    $('console-refresh').addEventListener('click', refreshState);
    $('estop').addEventListener('click', estop);
    panel.owner = gonio.owner();
    renderEnabled();
    setInterval(watchOwner, OWNER_CHECK_MS);
    if (panel.owner === null) refreshState();
  }

  start();
})();
