// The alignment card of the status page: starts the daemon's alignment (POST /api/align), shows its step and the
// operator's instruction while it runs (GET /api/align, polled), confirms an operator step on hardware, and lists
// the stored calibrations with the current one (GET /api/calibrations). It uses the page's API access
// (window.gonio, from status.js). Text from the daemon goes into the page as textContent, never as HTML.
'use strict';

(() => {
  const POLL_RUNNING_MS = 1000;
  const POLL_IDLE_MS = 10000;
  const $ = (id) => document.getElementById(id);
  const gonio = window.gonio;
  let timer = null;

  function say(text, isError = false) {
    const s = $('align-status');
    s.textContent = text;
    s.classList.toggle('error-text', isError);
  }

  function describe(a) {
    switch (a.state) {
      case 'idle': return 'No alignment since the daemon started.';
      case 'running': return 'Aligning (started by ' + a.started_by + '): ' + (a.step || '');
      case 'waiting-operator': return 'Waiting for the operator: ' + (a.operator_message || '');
      case 'completed': return 'Completed: calibration ' + a.calibration_id + ' is now applied to new campaigns.';
      case 'failed': return 'Failed: ' + (a.error || 'no reason given');
      default: return a.state;
    }
  }

  function renderCalibrations(list) {
    const current = list.find((c) => c.current);
    $('align-current').textContent = current
      ? 'Current calibration: ' + current.id + ', made ' + current.created_utc + ' (' + current.source + ').'
      : 'No calibration is applied to new campaigns.';
  }

  async function refresh() {
    let a = null;
    try {
      a = await (await gonio.api('/api/align')).json();
      $('align-state').textContent = describe(a);
      $('align-state').dataset.state = a.state;
      renderCalibrations(await (await gonio.api('/api/calibrations')).json());
    } catch (e) {
      say('cannot read the alignment: ' + e.message, true);
    }
    const busy = a !== null && (a.state === 'running' || a.state === 'waiting-operator');
    $('align-start').disabled = busy || gonio.owner() !== null;
    $('align-characterise').disabled = $('align-start').disabled;
    $('align-confirm').disabled = a === null || a.state !== 'waiting-operator';
    clearTimeout(timer);
    timer = setTimeout(refresh, busy ? POLL_RUNNING_MS : POLL_IDLE_MS);
  }

  async function post(path, json, what) {
    try {
      await gonio.api(path, { method: 'POST', json });
      say(what);
    } catch (e) {
      say('cannot ' + what + ': ' + e.message, true);
    }
    refresh();
  }

  function start() {
    if (!gonio) return;
    $('align-start').addEventListener('click', () =>
      post('/api/align', { characterise: $('align-characterise').checked }, 'start the alignment'));
    $('align-confirm').addEventListener('click', () => post('/api/align/confirm', {}, 'confirm the operator step'));
    refresh();
  }

  start();
})();
