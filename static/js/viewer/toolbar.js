// The viewer's toolbar: reset, fovea marking, streaming settings (target error, bandwidth,
// maximum wait, GPU memory, foveation α), a status line (what is drawn and streamed) and room
// for further tool groups (the region selection's, on a row of its own).

function button(label, title, onClick) {
  const b = document.createElement('button');
  b.type = 'button';
  b.textContent = label;
  b.title = title;
  b.addEventListener('click', onClick);
  return b;
}

function numberField(label, value, attrs, onChange) {
  const wrap = document.createElement('label');
  wrap.textContent = label;
  const input = document.createElement('input');
  input.type = 'number';
  Object.assign(input, attrs);
  input.value = String(value);
  input.addEventListener('change', () => {
    const v = Number(input.value);
    if (Number.isFinite(v)) onChange(v);
  });
  wrap.append(input);
  return wrap;
}

/**
 * @param {HTMLElement} host
 * @param {object} settings the streamer's settings (read for initial values)
 * @param {{reset: Function, toggleFoveaMode: (on: boolean) => void, clearFoveae: Function,
 *   setSettings: (changes: object) => void}} actions
 */
export function makeToolbar(host, settings, actions) {
  const bar = document.createElement('div');
  bar.className = 'viewer-toolbar';
  const fovea = button('Fovea', 'Mark a point of interest: the next click refines around it first (or Ctrl/Alt-click)', () => {
    const on = !fovea.classList.contains('active');
    fovea.classList.toggle('active', on);
    fovea.setAttribute('aria-pressed', String(on));
    actions.toggleFoveaMode(on);
  });
  fovea.setAttribute('aria-pressed', 'false');
  const clear = button('Clear foveae', 'Remove every point of interest', () => actions.clearFoveae());
  const reset = button('Reset view', 'Back to the whole model', () => actions.reset());
  const details = document.createElement('details');
  details.className = 'viewer-settings';
  const summary = document.createElement('summary');
  summary.textContent = 'Settings';
  details.append(
    summary,
    numberField('Target error (px) ', settings.pixelError, { min: 0.25, max: 16, step: 0.25 }, (v) => actions.setSettings({ pixelError: Math.max(0.25, v) })),
    numberField('Bandwidth (KB/s, 0 = measured) ', Math.round(settings.bandwidth / 1000), { min: 0, step: 50 }, (v) => actions.setSettings({ bandwidth: Math.max(0, v) * 1000 })),
    numberField('Max wait per refinement (s) ', settings.maxWait, { min: 0.1, max: 30, step: 0.1 }, (v) => actions.setSettings({ maxWait: Math.max(0.1, v) })),
    numberField('GPU memory (MB) ', Math.round(settings.gpuBudget / 1048576), { min: 16, step: 16 }, (v) => actions.setSettings({ gpuBudget: Math.max(16, v) * 1048576 })),
    numberField('Fovea sharpness α ', settings.alpha, { min: 0, max: 100, step: 1 }, (v) => actions.setSettings({ alpha: Math.max(0, v) })),
  );
  const status = document.createElement('div');
  status.className = 'viewer-status';
  status.setAttribute('aria-live', 'off');
  bar.append(reset, fovea, clear, details, status);
  host.appendChild(bar);
  return {
    setStatus(text) {
      status.textContent = text;
    },
    setFoveaMode(on) {
      fovea.classList.toggle('active', on);
      fovea.setAttribute('aria-pressed', String(on));
    },
    /** Appends a tool group (an element) after the status line. */
    addGroup(el) {
      bar.append(el);
    },
  };
}
