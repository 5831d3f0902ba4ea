// The inspector's working state as a document: the stack's entries (layers and their grades,
// groups), the exposure, the view, the comparison and the snapshots. Every edit goes through
// `History.edit`, which keeps what undo and redo need; the page persists the document beside
// the render (PUT /api/document) and gets it back on reload (/api/session's "document").
// Its shape is pxr_layers/view/document.py's, which validates it on the server.

export const FORMAT = 1;
export const HISTORY_LIMIT = 200;
/** Edits of one control within this many milliseconds are one step of undo (a slider's drag). */
export const COALESCE_MS = 1000;

/** A stack entry: one use of a server layer (`source`), with its own name and grade. */
export function newEntry(source, fields = {}) {
  return {
    id: fields.id ?? source.id, source: source.id, name: fields.name ?? source.name, kind: source.kind,
    expression: source.expression ?? '', group: fields.group ?? '', note: fields.note ?? '',
    stops: fields.stops ?? source.exposure ?? 0, tint: fields.tint ?? source.tint ?? [1, 1, 1],
    kelvin: fields.kelvin ?? null, mute: fields.mute ?? false, solo: fields.solo ?? false, mask: fields.mask ?? null,
  };
}

/** The grade fields of an entry (what a snapshot keeps and a reset restores). */
export const GRADE_KEYS = ['stops', 'tint', 'kelvin', 'mute', 'solo', 'mask'];

export function emptyDocument() {
  return {
    format: FORMAT, exposure: 0, entries: [], snapshots: [], saved: null,
    view: { fit: true, scale: 1, cx: 0.5, cy: 0.5 }, compare: { mode: 'one', against: 'beauty', wipe: 0.5 },
    denoised: false, display_view: null,
  };
}

const copy = (value) => JSON.parse(JSON.stringify(value));

/** Undo and redo over whole documents (they are small: no images). */
export class History {
  /** `kept`: keys of the document that undo and redo leave as they are (how it is viewed). */
  constructor(document, onChange, kept = ['view', 'compare', 'denoised', 'saved', 'display_view']) {
    this.document = document;
    this.onChange = onChange;  // (document, {structure}) after every edit, undo and redo
    this.kept = kept;
    this.undos = [];
    this.redos = [];
    this.last = { key: null, time: 0 };
  }

  /** Apply `change(document)`; one undo step, unless `key` names the same control as the edit
   *  just before, within COALESCE_MS. `structure`: entries were added, removed or moved. */
  edit(label, change, { key = null, structure = false } = {}) {
    const now = performance.now();
    const coalesce = key !== null && key === this.last.key && now - this.last.time < COALESCE_MS;
    if (!coalesce) {
      this.undos.push({ label, state: copy(this.document) });
      if (this.undos.length > HISTORY_LIMIT) this.undos.shift();
      this.redos = [];
    }
    this.last = { key, time: now };
    change(this.document);
    this.onChange(this.document, { structure, label });
  }

  get canUndo() { return this.undos.length > 0; }
  get canRedo() { return this.redos.length > 0; }
  get undoLabel() { return this.undos.at(-1)?.label ?? ''; }
  get redoLabel() { return this.redos.at(-1)?.label ?? ''; }

  undo() { return this.step(this.undos, this.redos); }
  redo() { return this.step(this.redos, this.undos); }

  step(from, to) {
    const step = from.pop();
    if (!step) return null;
    to.push({ label: step.label, state: copy(this.document) });
    // The same object stays the document (the page holds it): its contents are replaced.
    const kept = Object.fromEntries(this.kept.map((key) => [key, this.document[key]]));
    for (const key of Object.keys(this.document)) delete this.document[key];
    Object.assign(this.document, step.state, kept);
    this.last = { key: null, time: 0 };
    this.onChange(this.document, { structure: true, label: step.label });
    return step.label;
  }
}

/** `name`, or `name_2`, `name_3`… when `taken` has it. */
export function freeName(name, taken) {
  if (!taken.has(name)) return name;
  let number = 2;
  while (taken.has(`${name}_${number}`)) number += 1;
  return `${name}_${number}`;
}

/** Move the entry at `from` to `to` (indices into entries, both ≥ 1: the beauty stays first). */
export function moveEntry(entries, from, to) {
  if (from < 1 || to < 1 || from >= entries.length || to >= entries.length || from === to) return false;
  const [entry] = entries.splice(from, 1);
  entries.splice(to, 0, entry);
  return true;
}

/** Put entry `at` into `group` ('' none), next to the group's last member so groups stay runs. */
export function setGroup(entries, at, group) {
  const entry = entries[at];
  entry.group = group;
  if (!group) return;
  const last = entries.findLastIndex((other, i) => i !== at && other.group === group);
  if (last < 0) return;
  entries.splice(at, 1);
  entries.splice(last < at ? last + 1 : last, 0, entry);
}

/** What a snapshot keeps: the exposure and each entry with its grade. */
export function snapshotOf(document, name) {
  return {
    name, exposure: document.exposure,
    entries: document.entries.filter((entry) => entry.kind !== 'beauty').map((entry) => copy(entry)),
  };
}
