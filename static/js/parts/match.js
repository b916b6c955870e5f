// The words of a search query found again in rendered information, to mark them (<mark>) where
// the panel shows a search result. The server's index (src/search) splits text on
// non-alphanumeric characters, lower-cases, folds accents and stems English words; this applies
// the same splitting and folding and light suffix rules in place of the stemmer, so "survey"
// also marks "surveys" and "surveyed". Terms excluded by the query (`-word`) are not marked.

const WORD = /[\p{L}\p{N}]+/gu;
const OPERATORS = new Set(['and', 'or', 'not']);
const SUFFIXES = ['ingly', 'edly', 'ings', 'ing', 'ied', 'ies', 'ed', 'es', 'ly', 's'];

/** Lower case without diacritics (as tantivy's LowerCaser and AsciiFoldingFilter). */
export function fold(word) {
  return word.normalize('NFD').replace(/\p{M}/gu, '').toLowerCase();
}

/**
 * A folded word and its light English stems: each common suffix it ends with taken off (at least
 * three letters kept), so "noses" gives "nose" and "nos", "studies" gives "study". Two words
 * match when their variants meet.
 */
export function variants(word) {
  const out = [word];
  for (const s of SUFFIXES) {
    if (word.length - s.length >= 3 && word.endsWith(s)) {
      const base = word.slice(0, -s.length);
      out.push(s === 'ies' || s === 'ied' ? `${base}y` : base);
    }
  }
  return out;
}

/**
 * The folded words a query asks for: phrases split into their words, `field:` prefixes,
 * `+`, boosts and the operators AND/OR/NOT dropped, `-word` and `-"phrase"` left out.
 * @param {string} query
 * @returns {string[]}
 */
export function searchTerms(query) {
  const out = new Set();
  for (const m of String(query).matchAll(/(-?)"([^"]*)"?|(\S+)/g)) {
    if (m[1] === '-') continue;
    let text = m[2] !== undefined ? m[2] : m[3];
    if (m[3] !== undefined) {
      if (text.startsWith('-')) continue;
      text = text.replace(/^\+/, '').replace(/^[\p{L}_][\p{L}\p{N}_]*:/u, '').replace(/[~^][\d.]*$/, '');
      if (OPERATORS.has(text.toLowerCase())) continue;
    }
    for (const w of text.matchAll(WORD)) out.add(fold(w[0]));
  }
  return [...out];
}

/**
 * Wraps each word of `root`'s text matching one of `terms` (from [`searchTerms`]) in
 * `<mark class="search-match">`; returns the marks with the term each matched, in document order.
 * @param {Element} root
 * @param {string[]} terms
 * @returns {{mark: HTMLElement, term: string}[]}
 */
export function markTerms(root, terms) {
  const found = [];
  if (!terms.length) return found;
  const wanted = new Map();
  for (const t of terms) for (const v of variants(t)) if (!wanted.has(v)) wanted.set(v, t);
  const walker = root.ownerDocument.createTreeWalker(root, NodeFilter.SHOW_TEXT, {
    acceptNode: (n) => (n.parentElement && n.parentElement.closest('mark, script, style') ? NodeFilter.FILTER_REJECT : NodeFilter.FILTER_ACCEPT),
  });
  const nodes = [];
  while (walker.nextNode()) nodes.push(walker.currentNode);
  for (const node of nodes) {
    const text = node.nodeValue;
    const hits = [];
    for (const w of text.matchAll(WORD)) {
      const v = variants(fold(w[0])).find((x) => wanted.has(x));
      if (v !== undefined) hits.push({ start: w.index, end: w.index + w[0].length, term: wanted.get(v) });
    }
    if (!hits.length) continue;
    const frag = root.ownerDocument.createDocumentFragment();
    let at = 0;
    for (const h of hits) {
      if (h.start > at) frag.append(text.slice(at, h.start));
      const mark = root.ownerDocument.createElement('mark');
      mark.className = 'search-match';
      mark.textContent = text.slice(h.start, h.end);
      frag.append(mark);
      found.push({ mark, term: h.term });
      at = h.end;
    }
    if (at < text.length) frag.append(text.slice(at));
    node.replaceWith(frag);
  }
  return found;
}
