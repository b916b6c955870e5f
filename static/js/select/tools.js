// The *Select* group of the viewer's toolbar (editors and admins): the tools (lasso, markup,
// heavy lasso, segments, point), the mode (replace, add, subtract), the markup's background
// toggle, the brush width, the segments' scale, undo / confirm / cancel, *Edit region* for the part open in the panel, the
// draft's vertex count and the server's error messages.

const TOOLS = [
  ['lasso', 'Lasso', 'Drag a polygon around the region'],
  ['markup', 'Markup', 'Paint strokes on the region (foreground) and around it (background: Shift, right button or the Background toggle)'],
  ['heavy_lasso', 'Heavy lasso', 'Trace the boundary with one thick closed stroke'],
  ['segment', 'Segments', 'Hover to preview the surface segment under the cursor, click to select it (Shift: add, Alt: subtract)'],
  ['point', 'Point', 'Click a surface point: a point part'],
];
const MODES = [
  ['replace', 'Replace', 'The new selection replaces the current one'],
  ['add', 'Add', 'Add the new selection to the current one'],
  ['subtract', 'Subtract', 'Remove the new selection from the current one'],
];

function button(label, title, onClick, cls) {
  const b = document.createElement('button');
  b.type = 'button';
  b.textContent = label;
  b.title = title;
  if (cls) b.className = cls;
  b.addEventListener('click', onClick);
  return b;
}

function toggle(b, on) {
  b.classList.toggle('active', on);
  b.setAttribute('aria-pressed', String(on));
}

export class SelectTools {
  /**
   * @param {{setTool: (t: string|null) => void, setMode: (m: string) => void,
   *   setBackground: (on: boolean) => void, setBrush: (px: number) => void, undo: Function,
   *   confirm: Function, cancel: Function, editRegion: Function,
   *   setScale: (scale: number) => void}} actions
   * @param {{brush: number}} initial
   */
  constructor(actions, initial) {
    this.root = document.createElement('div');
    this.root.className = 'select-tools';
    this.root.setAttribute('role', 'group');
    this.root.setAttribute('aria-label', 'Select a region');
    const label = document.createElement('span');
    label.className = 'select-label';
    label.textContent = 'Select';
    this.tools = new Map();
    const tools = document.createElement('span');
    tools.className = 'select-buttons';
    for (const [id, text, title] of TOOLS) {
      const b = button(text, title, () => actions.setTool(b.classList.contains('active') ? null : id));
      b.dataset.tool = id;
      toggle(b, false);
      this.tools.set(id, b);
      tools.append(b);
    }
    this.modes = new Map();
    const modes = document.createElement('span');
    modes.className = 'select-buttons select-modes';
    modes.setAttribute('role', 'radiogroup');
    modes.setAttribute('aria-label', 'Mode');
    for (const [id, text, title] of MODES) {
      const b = button(text, title, () => actions.setMode(id));
      b.dataset.mode = id;
      b.setAttribute('role', 'radio');
      this.modes.set(id, b);
      modes.append(b);
    }
    this.background = button('Background', 'Markup: strokes mark the background (or hold Shift, or use the right button)', () =>
      actions.setBackground(!this.background.classList.contains('active')),
    );
    this.background.dataset.action = 'background';
    const brush = document.createElement('label');
    brush.className = 'select-brush';
    brush.textContent = 'Brush ';
    this.brush = document.createElement('input');
    this.brush.type = 'number';
    this.brush.min = '2';
    this.brush.max = '200';
    this.brush.step = '1';
    this.brush.value = String(initial.brush);
    this.brush.setAttribute('aria-label', 'Brush width in pixels');
    this.brush.addEventListener('change', () => {
      const v = Math.round(Number(this.brush.value));
      if (Number.isFinite(v) && v >= 2) actions.setBrush(Math.min(200, v));
    });
    brush.append(this.brush, ' px');
    this.brushLabel = brush;
    // The segments' scale: 0 (finest) on the left, the coarsest on the right.
    const scale = document.createElement('label');
    scale.className = 'select-scale';
    scale.textContent = 'Size ';
    this.scale = document.createElement('input');
    this.scale.type = 'range';
    this.scale.min = '0';
    this.scale.max = '0';
    this.scale.step = '1';
    this.scale.setAttribute('aria-label', 'Segment size: finer to the left, coarser to the right');
    this.scale.addEventListener('input', () => actions.setScale(Number(this.scale.value)));
    this.scaleCount = document.createElement('span');
    this.scaleCount.className = 'select-scale-count';
    scale.append(this.scale, this.scaleCount);
    this.scaleLabel = scale;
    this.undo = button('Undo', 'Back to the previous selection', () => actions.undo());
    this.undo.dataset.action = 'undo';
    this.confirm = button('Confirm', 'Make the selection a part', () => actions.confirm(), 'select-confirm');
    this.confirm.dataset.action = 'confirm';
    this.cancel = button('Cancel', 'Discard the selection (Escape)', () => actions.cancel());
    this.cancel.dataset.action = 'cancel';
    this.edit = button('Edit region', 'Edit the region of the part open in the panel', () => actions.editRegion());
    this.edit.dataset.action = 'edit-region';
    this.status = document.createElement('span');
    this.status.className = 'select-status';
    this.status.setAttribute('aria-live', 'polite');
    this.error = document.createElement('span');
    this.error.className = 'select-error';
    this.error.setAttribute('role', 'alert');
    this.error.hidden = true;
    this.root.append(label, tools, modes, this.background, brush, scale, this.undo, this.confirm, this.cancel, this.edit, this.status, this.error);
  }

  /**
   * @param {{tool: string|null, mode: string, background: boolean, busy: boolean,
   *   drafts: number, draft: object|null, editing: number|null, openPart: number|null,
   *   hint: string, segments: {scale: number|null, scales: number, count: number}}} s
   */
  render(s) {
    for (const [id, b] of this.tools) {
      toggle(b, s.tool === id);
      b.disabled = s.busy;
    }
    for (const [id, b] of this.modes) {
      b.classList.toggle('active', s.mode === id);
      b.setAttribute('aria-checked', String(s.mode === id));
      b.disabled = s.busy || s.tool === 'point';
    }
    toggle(this.background, s.background);
    this.background.hidden = s.tool !== 'markup';
    this.brushLabel.hidden = s.tool !== 'markup' && s.tool !== 'heavy_lasso';
    const seg = s.segments;
    this.scaleLabel.hidden = s.tool !== 'segment' || !seg || seg.scale === null;
    if (seg && seg.scale !== null) {
      this.scale.max = String(Math.max(0, seg.scales - 1));
      if (document.activeElement !== this.scale) this.scale.value = String(seg.scale);
      this.scaleCount.textContent = ` ${seg.count.toLocaleString()} segments`;
    }
    this.undo.disabled = s.busy || s.drafts === 0;
    this.confirm.disabled = s.busy || s.draft === null;
    this.cancel.disabled = s.busy || (s.drafts === 0 && s.tool === null && s.editing === null);
    this.edit.hidden = s.openPart === null || s.editing === s.openPart;
    this.edit.disabled = s.busy;
    this.root.classList.toggle('busy', s.busy);
    const parts = [];
    if (s.editing !== null) parts.push(`editing part ${s.editing}`);
    if (s.busy) parts.push('selecting…');
    else if (s.draft) {
      const d = s.draft;
      const delta = d.base || d.part_id ? ` (+${d.added.toLocaleString()} / −${d.removed.toLocaleString()})` : '';
      parts.push(`${d.vertex_count.toLocaleString()} ${d.vertex_count === 1 ? 'vertex' : 'vertices'}${delta}`);
    } else if (s.hint) parts.push(s.hint);
    this.status.textContent = parts.join(' · ');
    if (s.draft && !s.busy) this.status.dataset.vertexCount = String(s.draft.vertex_count);
    else delete this.status.dataset.vertexCount;
  }

  showError(message) {
    this.error.textContent = message;
    this.error.hidden = !message;
  }
}
