// The JSON API as the selection tools use it: same-origin requests carrying the session's
// CSRF token on every state-changing call, and the server's `{"error": "..."}` answers turned
// into errors whose message is the server's own.

/** An API failure: the HTTP status and the server's message. */
export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.name = 'ApiError';
    this.status = status;
  }
}

/** The session's CSRF token: the viewer's `data-csrf`, else a form's hidden field. */
export function csrfToken(root) {
  if (root && root.dataset.csrf) return root.dataset.csrf;
  const input = document.querySelector('input[name=csrf_token]');
  return input ? input.value : '';
}

async function failure(res) {
  const text = await res.text().catch(() => '');
  let message = '';
  try {
    message = JSON.parse(text).error || '';
  } catch {
    message = text.trim().slice(0, 300);
  }
  return new ApiError(res.status, message || `HTTP ${res.status} ${res.statusText}`.trim());
}

export class Api {
  /** @param {string} csrf */
  constructor(csrf) {
    this.csrf = csrf;
  }

  /** A request; `body`: an object (sent as JSON), FormData, or nothing. Resolves to the Response. */
  async send(method, url, body) {
    const headers = { Accept: 'application/json' };
    if (method !== 'GET' && method !== 'HEAD') headers['X-CSRF-Token'] = this.csrf;
    let payload;
    if (body instanceof FormData) payload = body;
    else if (body !== undefined) {
      headers['Content-Type'] = 'application/json';
      payload = JSON.stringify(body);
    }
    let res;
    try {
      res = await fetch(url, { method, headers, body: payload, credentials: 'same-origin' });
    } catch (e) {
      throw new ApiError(0, `the server cannot be reached (${e.message})`);
    }
    if (!res.ok) throw await failure(res);
    return res;
  }

  /** The JSON answer (null for 204). */
  async json(method, url, body) {
    const res = await this.send(method, url, body);
    if (res.status === 204) return null;
    const text = await res.text();
    return text ? JSON.parse(text) : null;
  }

  async bytes(url) {
    return (await this.send('GET', url)).arrayBuffer();
  }

  get(url) {
    return this.json('GET', url);
  }

  post(url, body) {
    return this.json('POST', url, body);
  }

  put(url, body) {
    return this.json('PUT', url, body);
  }

  delete(url) {
    return this.json('DELETE', url);
  }
}
