// The viewer's toolbar: reset, focus points (foveae: the next click refines around a point
// first), the View menu (lighting, background, sharpness; under "Advanced" the streaming
// settings and what the streaming does, in figures), a status line in plain words, and room
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

/** A group of radio buttons `[value, label]`, `value` checked. */
export function choice(legend, name, options, value, onChange) {
  const set = document.createElement('fieldset');
  set.className = 'viewer-choice';
  const l = document.createElement('legend');
  l.textContent = legend;
  set.append(l);
  for (const [v, text] of options) {
    const label = document.createElement('label');
    const input = document.createElement('input');
    input.type = 'radio';
    input.name = name;
    input.value = v;
    input.checked = v === value;
    input.addEventListener('change', () => {
      if (input.checked) onChange(v);
    });
    label.append(input, ` ${text}`);
    set.append(label);
  }
  return set;
}

/** Lighting presets: the label, and what scene.js needs. */
export const LIGHTING = {
  headlight: { label: 'Headlight', mode: 'headlight', ambient: 0.25 },
  soft: { label: 'Soft', mode: 'headlight', ambient: 0.55 },
  raking: { label: 'Raking light (reveals relief)', mode: 'raking', ambient: 0.2 },
};

/** Background presets. */
export const BACKGROUNDS = {
  dark: { label: 'Dark', color: 0x1d2026 },
  grey: { label: 'Grey', color: 0x777c80 },
  white: { label: 'White', color: 0xffffff },
  black: { label: 'Black', color: 0x000000 },
};

/**
 * @param {HTMLElement} host
 * @param {object} settings the streamer's settings (read for initial values)
 * @param {{lighting: string, background: string}} look the chosen presets
 * @param {{reset: Function, toggleFoveaMode: (on: boolean) => void, clearFoveae: Function,
 *   setSettings: (changes: object) => void, setLook: (changes: object) => void}} actions
 */
export function makeToolbar(host, settings, look, actions) {
  const bar = document.createElement('div');
  bar.className = 'viewer-toolbar';
  const fovea = button('Focus point', 'Mark a point of interest: the next click makes it sharp first (or Ctrl/Alt-click)', () => {
    const on = !fovea.classList.contains('active');
    fovea.classList.toggle('active', on);
    fovea.setAttribute('aria-pressed', String(on));
    actions.toggleFoveaMode(on);
  });
  fovea.setAttribute('aria-pressed', 'false');
  const clear = button('Clear focus', 'Remove every point of interest', () => actions.clearFoveae());
  clear.hidden = true;
  const reset = button('Reset view', 'Back to the whole model (Home key)', () => actions.reset());

  const menu = document.createElement('details');
  menu.className = 'viewer-settings';
  const summary = document.createElement('summary');
  summary.textContent = 'View';
  const panel = document.createElement('div');
  panel.className = 'settings-panel';
  const advanced = document.createElement('details');
  advanced.className = 'viewer-advanced';
  const advSummary = document.createElement('summary');
  advSummary.textContent = 'Advanced: streaming';
  const details = document.createElement('p');
  details.className = 'viewer-details';
  details.setAttribute('aria-live', 'off');
  advanced.append(
    advSummary,
    details,
    numberField('Download limit (KB/s, 0 = as fast as the link allows) ', Math.round(settings.bandwidth / 1000), { min: 0, step: 50 }, (v) => actions.setSettings({ bandwidth: Math.max(0, v) * 1000 })),
    numberField('Longest wait for more detail (s) ', settings.maxWait, { min: 0.1, max: 30, step: 0.1 }, (v) => actions.setSettings({ maxWait: Math.max(0.1, v) })),
    numberField('Graphics memory for the model (MB) ', Math.round(settings.gpuBudget / 1048576), { min: 16, step: 16 }, (v) => actions.setSettings({ gpuBudget: Math.max(16, v) * 1048576 })),
    numberField('How fast detail falls off around a focus point (α) ', settings.alpha, { min: 0, max: 100, step: 1 }, (v) => actions.setSettings({ alpha: Math.max(0, v) })),
  );
  const keys = document.createElement('p');
  keys.className = 'viewer-keys';
  keys.textContent = 'Keyboard (click the view first): arrows turn, Shift+arrows move, + and − zoom, Home resets.';
  panel.append(
    choice('Lighting', 'viewer-lighting', Object.entries(LIGHTING).map(([k, v]) => [k, v.label]), look.lighting, (v) => actions.setLook({ lighting: v })),
    choice('Background', 'viewer-background', Object.entries(BACKGROUNDS).map(([k, v]) => [k, v.label]), look.background, (v) => actions.setLook({ background: v })),
    numberField('Sharpness: largest error (pixels) ', settings.pixelError, { min: 0.25, max: 16, step: 0.25 }, (v) => actions.setSettings({ pixelError: Math.max(0.25, v) })),
    keys,
    advanced,
  );
  menu.append(summary, panel);
  // The menu closes on Escape and on a click elsewhere.
  menu.addEventListener('keydown', (e) => {
    if (e.key === 'Escape' && menu.open) {
      e.preventDefault();
      menu.open = false;
      summary.focus();
    }
  });
  document.addEventListener('pointerdown', (e) => {
    if (menu.open && !menu.contains(e.target)) menu.open = false;
  });

  const status = document.createElement('div');
  status.className = 'viewer-status';
  status.setAttribute('aria-live', 'off');
  bar.append(reset, fovea, clear, menu, status);
  host.appendChild(bar);
  return {
    element: bar,
    /** The status line: plain words. */
    setStatus(text) {
      if (status.textContent !== text) status.textContent = text;
    },
    /** The streaming figures under "Advanced". */
    setDetails(text) {
      if (menu.open && advanced.open && details.textContent !== text) details.textContent = text;
    },
    setFoveaMode(on) {
      fovea.classList.toggle('active', on);
      fovea.setAttribute('aria-pressed', String(on));
    },
    /** Shows "Clear focus" while there are focus points. */
    setFoveaCount(n) {
      clear.hidden = n === 0;
    },
    /** Adds a setting (an element) to the View menu, before the keyboard help. */
    addSetting(el) {
      panel.insertBefore(el, keys);
    },
    /** Appends a tool group (an element) after the status line. */
    addGroup(el) {
      bar.append(el);
    },
  };
}
