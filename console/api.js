// The server's API as the console uses it: the key (kept in sessionStorage, so for this
// browser tab only, never on disk beyond it), JSON errors turned into ApiError with the
// server's message, and what the key may do (GET /v1/caller).

const KEY = "b2tf.apiKey";

export class ApiError extends Error {
  constructor(status, kind, message) {
    super(message);
    this.status = status;
    this.kind = kind;
  }
}

export const session = { caller: null };

let unauthorized = () => {};
// What to do when the server answers 401 (the console asks for a key).
export function onUnauthorized(f) {
  unauthorized = f;
}

export const key = () => sessionStorage.getItem(KEY);
export function setKey(k) {
  if (k) sessionStorage.setItem(KEY, k);
  else sessionStorage.removeItem(KEY);
}

// Whether the key may do what `scope` allows (read, write, admin); before the caller is
// known, assume yes and let the server decide.
export const can = (scope) => !session.caller || session.caller.scopes.includes(scope);

// One call. `body`: an object (sent as JSON) or FormData. Answers the parsed JSON, the
// text, or with {raw: true} the Response itself.
export async function call(method, path, body = null, { raw = false } = {}) {
  const headers = {};
  const k = key();
  if (k) headers.Authorization = `Bearer ${k}`;
  let payload = body;
  if (body !== null && !(body instanceof FormData)) {
    headers["Content-Type"] = "application/json";
    payload = JSON.stringify(body);
  }
  let resp;
  try {
    resp = await fetch(path, { method, headers, body: payload });
  } catch (e) {
    throw new ApiError(0, "unavailable", `the server did not answer (${e.message})`);
  }
  if (!resp.ok) {
    let kind = "";
    let message = `${resp.status} ${resp.statusText}`;
    try {
      const j = await resp.json();
      kind = j.error?.kind ?? "";
      message = j.error?.message ?? message;
    } catch {
      // Not a JSON error body (a proxy's page): the status line says enough.
    }
    const err = new ApiError(resp.status, kind, message);
    if (resp.status === 401) unauthorized(err);
    throw err;
  }
  if (raw) return resp;
  if (resp.status === 204) return null;
  const type = resp.headers.get("content-type") || "";
  return type.includes("json") ? resp.json() : resp.text();
}

// An image the API answers (it needs the key, so not a plain <img src>), as a blob: URL.
export async function imageUrl(path) {
  const resp = await call("GET", path, null, { raw: true });
  return URL.createObjectURL(await resp.blob());
}

export async function whoAmI() {
  session.caller = await call("GET", "/v1/caller");
  return session.caller;
}
