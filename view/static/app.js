// lightfold live view: the page side of docs/live-view.md. Plain script, no dependencies.
'use strict';

(() => {
  const ORBIT_DEG_PER_PX = 0.3;
  const KEY_ORBIT_DEG = 5;
  const ZOOM_PER_NOTCH = 1.1;
  const LIGHT_THROTTLE_MS = 100;
  const NOTICE_MS = 6000;
  const SEGMENTS = [
    ['shadow', 'shadow_us'], ['eye', 'eye_us'], ['readback', 'readback_us'],
    ['pack', 'pack_us'], ['send', 'send_us'], ['composite', 'composite_us'],
  ];

  // The page's state, for automated tests: frames received, the last header received and the
  // one on screen (`displayed`), the last acked steering revision, steering messages awaiting
  // their ack (`unacked`), the server's error messages, the camera, whether this viewer may
  // steer (`canSteer`), whether it sees the session at all (`canWatch`: beyond loopback without
  // the token, only with --public-watch) and whether the view takes the token over this
  // connection (`tokenAccepted`: not over plain HTTP beyond loopback), the last status, the exposure frames are encoded at (stops), the playback (`clock`:
  // the clip time of the frame on screen, the one clock the page shows) and the camera bookmarks.
  const view = (window.lightfoldView = {
    connected: false, frames: 0, header: null, displayed: null, revision: null, unacked: 0, errors: [],
    ended: null,
    camera: null, canSteer: false, canWatch: true, tokenAccepted: true, status: null, scene: null, lights: [],
    exposure: null, clock: null, playback: null, bookmarks: [],
  });

  const $ = (id) => document.getElementById(id);
  const el = (tag, attrs, ...kids) => {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === 'class') e.className = v;
      else if (k === 'text') e.textContent = v;
      else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
      else e.setAttribute(k, v);
    }
    for (const k of kids) if (k != null) e.append(k);
    return e;
  };
  const SVGNS = 'http://www.w3.org/2000/svg';
  const svg = (tag, attrs, text) => {
    const e = document.createElementNS(SVGNS, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    if (text != null) e.textContent = text;
    return e;
  };
  const ms = (v) => (v == null || !isFinite(v) ? '–' : v >= 100 ? `${v.toFixed(0)} ms` : `${v.toFixed(1)} ms`);
  const bytes = (b) => {
    if (b == null) return '–';
    if (b < 1024) return `${b} B`;
    if (b < 1048576) return `${(b / 1024).toFixed(1)} KiB`;
    return `${(b / 1048576).toFixed(2)} MiB`;
  };
  // Epochs are 64-bit ids beyond a double's exact range: parsed as strings, shown as their
  // ordinal among the epochs the status lists (the full id in the tooltip).
  const parseJson = (text) => JSON.parse(text.replace(/("epoch"\s*:\s*)(\d{16,})/g, '$1"$2"'));
  const epochLabel = (e) => {
    if (e == null) return '–';
    const i = (view.status?.epochs || []).findIndex((x) => String(x.epoch) === String(e));
    return i >= 0 ? `#${i + 1}` : `…${String(e).slice(-4)}`;
  };
  const fmtVec = (v) => (Array.isArray(v) ? v.map((x) => Number(x).toFixed(2)).join(', ') : '–');

  // ---- sRGB <-> linear --------------------------------------------------------------------
  const toLinear = (c) => (c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4));
  const toSrgb = (c) => (c <= 0.0031308 ? c * 12.92 : 1.055 * Math.pow(c, 1 / 2.4) - 0.055);
  const linearToHex = (rgb) => '#' + rgb.map((c) => {
    const v = Math.round(Math.min(1, Math.max(0, toSrgb(Math.max(0, c)))) * 255);
    return v.toString(16).padStart(2, '0');
  }).join('');
  const hexToLinear = (hex) => [1, 3, 5].map((i) => toLinear(parseInt(hex.slice(i, i + 2), 16) / 255));

  // ---- socket -----------------------------------------------------------------------------
  let ws = null;
  let backoff = 500;
  let nextId = 1;
  let firstFrameTimer = null;

  function connect() {
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const sock = new WebSocket(`${proto}//${location.host}/ws`);
    sock.binaryType = 'arraybuffer';
    ws = sock;
    setConn('connecting…', 'off');
    sock.onopen = () => { view.connected = true; view.ended = null; setConn('connected', 'on'); };
    sock.onmessage = (ev) => {
      if (typeof ev.data === 'string') onText(ev.data);
      else onFrame(ev.data);
    };
    sock.onclose = () => {
      if (ws !== sock) return;
      view.connected = false;
      view.unacked = 0;
      ws = null;
      const wait = Math.round(backoff * (0.75 + Math.random() * 0.5));
      const again = `reconnecting in ${(wait / 1000).toFixed(1)} s`;
      setConn(view.ended ? `${view.ended} (${again})` : again, 'off');
      backoff = Math.min(backoff * 2, 15000);
      setTimeout(connect, wait);
    };
    sock.onerror = () => { /* onclose follows */ };
  }

  function setConn(text, cls) {
    const c = $('conn');
    c.textContent = text;
    c.className = `pill ${cls}`;
  }

  /// Sends a message; steering messages get an id, answered by an ack (or by an error with
  /// that id when refused).
  function send(msg, steer = true) {
    if (!ws || ws.readyState !== WebSocket.OPEN) return false;
    if (steer) {
      if (!view.canSteer) { toast('watch only: present the token to steer', 'error'); return false; }
      msg.id = nextId++;
      view.unacked += 1;
    }
    ws.send(JSON.stringify(msg));
    return true;
  }

  function onText(data) {
    let m;
    try { m = parseJson(data); } catch (e) { log(`bad message: ${data.slice(0, 80)}`); return; }
    switch (m.type) {
      case 'welcome': return onWelcome(m);
      case 'camera': view.camera = m.camera; showCamera(); drawMarkers(); return;
      case 'animation': return showAnimation(m.animation || {});
      case 'exposure': return showExposure(m.stops);
      case 'lights': return onLights(m.lights || []);
      case 'moves': return onMoves(m.moves || []);
      case 'object': return onObject(m);
      case 'status': view.status = m; return showStatus(m);
      case 'ack':
        view.unacked = Math.max(0, view.unacked - 1);
        if (typeof m.revision === 'number') view.revision = Math.max(view.revision ?? m.revision, m.revision);
        return;
      case 'notice': log(m.text); return toast(m.text, 'notice');
      case 'ended':
        // The cluster's session is over: say why, and keep saying it while reconnecting.
        view.ended = m.text;
        log(m.text);
        setConn(m.text, 'off');
        return toast(m.text, 'error');
      case 'error':
        // A refused steering message: its error carries its id, in place of the ack.
        if (typeof m.id === 'number') view.unacked = Math.max(0, view.unacked - 1);
        view.errors.push(m.text);
        if (view.errors.length > 50) view.errors.shift();
        log(`error: ${m.text}`);
        return toast(m.text, 'error');
      default: log(`unknown message ${m.type}`);
    }
  }

  let tokenTried = false;
  // The scene's clock: the server plays it (speed, loop) and stamps every frame with the clip
  // time it was rendered at; the page shows one clock, the clip time of the frame on screen.
  const anim = { span: 0, playing: false, loop: true, speed: 1, at: 0, time: 0 };
  let seeking = false; // the user holds the time slider
  const fmtClip = (t) => `${Number(t).toFixed(2)} / ${anim.span.toFixed(2)} s`;
  function showAnimation(a) {
    anim.span = a.span || 0;
    anim.playing = !!a.playing;
    anim.loop = a.loop !== false;
    anim.speed = a.speed || 1;
    anim.time = a.time || 0;
    anim.at = performance.now();
    view.playback = { span: anim.span, playing: anim.playing, loop: anim.loop, speed: anim.speed };
    $('anim').hidden = !(anim.span > 0);
    $('time').max = String(anim.span || 1);
    $('loop').checked = anim.loop;
    const sp = $('speed');
    if (![...sp.options].some((o) => Number(o.value) === anim.speed)) sp.append(el('option', { value: String(anim.speed), text: `${anim.speed}×` }));
    sp.value = String([...sp.options].find((o) => Number(o.value) === anim.speed).value);
    showClock();
  }
  // Whether the clock still runs: a clip that does not loop stops at its end.
  const running = () => anim.playing && (anim.loop || anim.time + (performance.now() - anim.at) / 1000 * anim.speed < anim.span);
  function showClock() {
    if (!(anim.span > 0)) return;
    const t = view.displayed?.time;
    if (typeof t === 'number') {
      view.clock = t;
      // Not under the user's hand while they drag it.
      if (!seeking) $('time').value = String(t);
      $('time-label').textContent = fmtClip(t);
    }
    $('btn-play').textContent = running() ? 'pause' : 'play';
  }
  // The play button follows a clip that stops at its end.
  setInterval(() => { if (anim.playing) showClock(); }, 250);
  function togglePlay() {
    send({ type: running() ? 'pause' : 'play' });
  }

  // The token this page presented and the view took: sent with frame downloads too
  // (`Authorization: Bearer`), which a viewer beyond loopback needs unless the view is public.
  let presented = null;
  let heldToken = null;
  function presentToken(token) {
    presented = { token };
    send({ type: 'hello', token }, false);
  }

  function onWelcome(m) {
    backoff = 500;
    view.canSteer = !!m.can_steer;
    // A viewer beyond loopback without the token sees nothing of the session unless the view
    // was started with --public-watch; and over plain HTTP the view does not take the token from
    // it at all (it would cross the network readable): the page says so instead of sending it.
    view.canWatch = m.can_watch !== false;
    view.tokenAccepted = m.token_accepted !== false;
    if (view.canSteer && presented) heldToken = presented.token;
    view.scene = m.scene || null;
    view.camera = m.camera || null;
    if (typeof m.revision === 'number') view.revision = m.revision;
    $('watch-only').hidden = view.canSteer;
    document.body.classList.toggle('watch', !view.canSteer);
    const access = $('access-text');
    access.replaceChildren();
    if (!view.tokenAccepted) {
      access.append(el('b', { text: view.canWatch ? 'Watch only. ' : 'No view without the token. ' }), m.text || '');
    } else if (!view.canWatch) {
      access.append(el('b', { text: 'Token needed. ' }), 'This view shows its frames only to viewers who present the token.');
    } else {
      access.append(el('b', { text: 'Watch only. ' }), 'This page is served beyond loopback; present the token to steer.');
    }
    $('token-form').hidden = !view.tokenAccepted;
    $('placeholder').textContent = view.canWatch ? 'waiting for the first frame…'
      : view.tokenAccepted ? 'present the token to watch' : 'this view shows nothing here without the token';
    const s = m.scene || {};
    $('scene-name').textContent = s.name ? `${s.name} · ${s.width}×${s.height}${m.continuous ? ' · continuous' : ''}${m.walkthrough ? ' · walkthrough' : ''}` : '';
    buildLights(s.lights || []);
    showScenes(m.scenes);
    showAnimation(m.animation || {});
    setupExposure(m.exposure || {});
    loadBookmarks();
    showCamera();
    fitFrame();
    // A token in the address (`#token=…`, never sent to the server in a request line) is
    // presented once, so a link printed by the coordinator opens a view that steers.
    const fromUrl = new URLSearchParams(location.hash.slice(1)).get('token');
    if (!view.canSteer && view.tokenAccepted && fromUrl && !tokenTried) {
      tokenTried = true;
      presentToken(fromUrl);
    } else if (!view.canSteer && view.tokenAccepted && heldToken) {
      // Reconnected: the token the view took before, once per connection.
      const t = heldToken;
      heldToken = null;
      presentToken(t);
    }
    // Ask for a frame if none comes of its own accord (the view renders only on change).
    clearTimeout(firstFrameTimer);
    if (view.canSteer && !view.displayed) {
      firstFrameTimer = setTimeout(() => { if (!view.frames) send({ type: 'render' }); }, 1500);
    }
  }

  // The scenes this view offers (`scenes: {names, current}`; absent: none to pick).
  function showScenes(scenes) {
    const box = $('scene-box');
    box.hidden = !scenes || !Array.isArray(scenes.names);
    if (box.hidden) return;
    const pick = $('scene-pick');
    pick.replaceChildren(...scenes.names.map((n) => el('option', { text: n, value: n })));
    if (scenes.names.includes(scenes.current)) pick.value = scenes.current;
  }

  $('scene-form').addEventListener('submit', (e) => {
    e.preventDefault();
    const name = $('scene-pick').value;
    if (name && send({ type: 'scene_open', name })) toast(`opening ${name}…`, 'notice');
  });

  // ---- frames -----------------------------------------------------------------------------
  const img = $('frame');
  const urls = [];
  let lastArrival = 0;
  let fps = null;

  function onFrame(buf) {
    if (buf.byteLength < 4) return;
    const n = new DataView(buf).getUint32(0, false);
    if (4 + n > buf.byteLength) { log('truncated frame'); return; }
    let header;
    try { header = parseJson(new TextDecoder().decode(new Uint8Array(buf, 4, n))); } catch (e) { log('bad frame header'); return; }
    const url = URL.createObjectURL(new Blob([new Uint8Array(buf, 4 + n)], { type: 'image/jpeg' }));
    urls.push(url);
    img.onload = () => {
      // Revoke every URL older than the one now shown.
      while (urls.length && urls[0] !== url) URL.revokeObjectURL(urls.shift());
      img.style.visibility = 'visible';
      $('placeholder').hidden = true;
      view.displayed = header;
      fitFrame();
      showClock();
    };
    img.onerror = () => log(`frame ${header.frame}: JPEG did not decode`);
    img.src = url;
    view.frames += 1;
    view.header = header;
    // A frame encoded again at a new exposure is no new frame from the cluster.
    if (header.reencoded) return;
    const now = performance.now();
    if (lastArrival) {
      const inst = 1000 / Math.max(1, now - lastArrival);
      fps = fps == null ? inst : fps * 0.8 + inst * 0.2;
    }
    lastArrival = now;
    $('st-frame').textContent = header.frame;
    $('st-epoch').textContent = epochLabel(header.epoch);
    $('st-epoch').title = `epoch ${header.epoch}`;
    $('st-interval').textContent = ms(header.interval_ms);
    $('st-latency').textContent = ms(header.latency_ms);
    $('st-fps').textContent = fps == null ? '–' : fps.toFixed(1);
    const r = header.refine;
    $('st-refine').textContent = r
      ? `${r.level}/${r.of}${r.samples ? ` · ${r.samples} spl` : ''}${r.aa > 1 ? ` · ${r.aa}× aa` : ''}`
      : 'no';
    scheduleTimings(header);
  }

  // Sizes the frame to fill the viewport at the scene's aspect ratio.
  function fitFrame() {
    const vp = $('viewport');
    const w = img.naturalWidth || view.scene?.width;
    const h = img.naturalHeight || view.scene?.height;
    if (!w || !h) return;
    const s = Math.min(vp.clientWidth / w, vp.clientHeight / h);
    img.style.width = `${Math.floor(w * s)}px`;
    img.style.height = `${Math.floor(h * s)}px`;
    drawMarkers();
  }
  new ResizeObserver(fitFrame).observe($('viewport'));

  // ---- camera control ---------------------------------------------------------------------
  const vp = $('viewport');
  const pending = { yaw: 0, pitch: 0, px: 0, py: 0, zoom: 1 };
  let drag = null;
  let flushQueued = false;

  function queueFlush() {
    if (flushQueued) return;
    flushQueued = true;
    requestAnimationFrame(flush);
  }

  // At most one message of each kind per animation frame.
  function flush() {
    flushQueued = false;
    if (pending.yaw || pending.pitch) send({ type: 'orbit', yaw_deg: pending.yaw, pitch_deg: pending.pitch });
    if (pending.px || pending.py) send({ type: 'pan', x: pending.px, y: pending.py });
    if (pending.zoom !== 1) send({ type: 'zoom', factor: pending.zoom });
    Object.assign(pending, { yaw: 0, pitch: 0, px: 0, py: 0, zoom: 1 });
  }

  vp.addEventListener('contextmenu', (e) => e.preventDefault());
  vp.addEventListener('mousedown', (e) => {
    if (e.button !== 0 && e.button !== 2) return;
    e.preventDefault();
    vp.focus();
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    vp.classList.add(drag.pan ? 'panning' : 'orbiting');
  });
  window.addEventListener('mousemove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x;
    const dy = e.clientY - drag.y;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (!dx && !dy) return;
    if (drag.pan) {
      const r = img.getBoundingClientRect();
      pending.px -= dx / Math.max(1, r.width);
      pending.py += dy / Math.max(1, r.height);
    } else {
      pending.yaw -= dx * ORBIT_DEG_PER_PX;
      pending.pitch += dy * ORBIT_DEG_PER_PX;
    }
    queueFlush();
  });
  window.addEventListener('mouseup', () => {
    if (!drag) return;
    drag = null;
    vp.classList.remove('panning', 'orbiting');
  });
  vp.addEventListener('wheel', (e) => {
    e.preventDefault();
    const notches = e.deltaMode === 1 ? e.deltaY / 3 : e.deltaMode === 2 ? e.deltaY : e.deltaY / 100;
    pending.zoom *= Math.pow(ZOOM_PER_NOTCH, notches);
    queueFlush();
  }, { passive: false });

  window.addEventListener('keydown', (e) => {
    const t = e.target;
    if (t && (t.tagName === 'INPUT' || t.tagName === 'TEXTAREA' || t.tagName === 'SELECT' || t.isContentEditable)) return;
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    const k = e.key.length === 1 ? e.key.toLowerCase() : e.key;
    const orbit = {
      ArrowLeft: [KEY_ORBIT_DEG, 0], a: [KEY_ORBIT_DEG, 0],
      ArrowRight: [-KEY_ORBIT_DEG, 0], d: [-KEY_ORBIT_DEG, 0],
      ArrowUp: [0, -KEY_ORBIT_DEG], w: [0, -KEY_ORBIT_DEG],
      ArrowDown: [0, KEY_ORBIT_DEG], s: [0, KEY_ORBIT_DEG],
    }[k];
    if (orbit) { pending.yaw += orbit[0]; pending.pitch += orbit[1]; queueFlush(); }
    else if (k === '+' || k === '=') { pending.zoom /= ZOOM_PER_NOTCH; queueFlush(); }
    else if (k === '-' || k === '_') { pending.zoom *= ZOOM_PER_NOTCH; queueFlush(); }
    else if ((k === 'q' || k === 'e' || k === '[' || k === ']') && turnOrScaleObject(k)) { /* sent */ }
    else if (k === 'r') send({ type: 'reset' });
    else if (k === 'p' && anim.span > 0) togglePlay();
    else if (k === ' ') send({ type: 'render' });
    else return;
    e.preventDefault();
  });
  $('btn-reset').addEventListener('click', () => send({ type: 'reset' }));
  $('btn-play').addEventListener('click', togglePlay);
  $('time').addEventListener('pointerdown', () => { seeking = true; });
  window.addEventListener('pointerup', () => { if (seeking) { seeking = false; showClock(); } });
  $('time').addEventListener('input', () => {
    const t = Number($('time').value);
    $('time-label').textContent = fmtClip(t);
    send({ type: 'time', t });
  });
  $('loop').addEventListener('change', () => send({ type: 'loop', on: $('loop').checked }));
  $('speed').addEventListener('change', () => send({ type: 'speed', speed: Number($('speed').value) }));
  $('btn-render').addEventListener('click', () => send({ type: 'render' }));
  $('budget-form').addEventListener('submit', (e) => {
    e.preventDefault();
    const v = $('budget').value.trim();
    send({ type: 'budget', ms: v === '' ? null : Number(v) });
  });
  $('token-form').addEventListener('submit', (e) => {
    e.preventDefault();
    const token = $('token').value;
    if (token && view.tokenAccepted) presentToken(token);
  });
  // Downloads carry the token the view took (a link alone would be refused beyond loopback).
  for (const id of ['dl-png', 'dl-jpg', 'exr']) {
    $(id).addEventListener('click', async (e) => {
      if (!heldToken) return; // loopback or a public view: the plain link works
      e.preventDefault();
      const a = e.currentTarget;
      try {
        const r = await fetch(a.getAttribute('href'), { headers: { Authorization: `Bearer ${heldToken}` } });
        if (!r.ok) { toast(`${a.getAttribute('href')}: ${r.status} ${await r.text()}`, 'error'); return; }
        const url = URL.createObjectURL(await r.blob());
        const tmp = el('a', { href: url, download: a.getAttribute('download') });
        document.body.append(tmp);
        tmp.click();
        tmp.remove();
        setTimeout(() => URL.revokeObjectURL(url), 10000);
      } catch (err) { toast(`download failed: ${err.message}`, 'error'); }
    });
  }

  function showCamera() {
    const c = view.camera;
    $('camera').textContent = c ? `camera  position ${fmtVec(c.position)}  target ${fmtVec(c.target)}  fov ${Number(c.fov_y_deg).toFixed(1)}°` : '';
    // The numeric fields follow the camera, except while the user is typing in them.
    if (!c || $('camera-form').contains(document.activeElement)) return;
    const round = (x) => String(Math.round(Number(x) * 1e4) / 1e4);
    CAM_FIELDS.forEach(([id, key, i]) => { $(id).value = round(i == null ? c[key] : c[key][i]); });
  }

  // ---- numeric camera and bookmarks -------------------------------------------------------
  const CAM_FIELDS = [
    ['cam-px', 'position', 0], ['cam-py', 'position', 1], ['cam-pz', 'position', 2],
    ['cam-tx', 'target', 0], ['cam-ty', 'target', 1], ['cam-tz', 'target', 2],
    ['cam-fov', 'fov_y_deg', null],
  ];
  // Sends a camera edit (the server checks it: finite, the field of view within 1°–179°, a
  // camera that does not sit on its target nor look along its up axis).
  function sendCamera(c) {
    return send({ type: 'camera', camera: { position: c.position, target: c.target, up: c.up, fov_y_deg: c.fov_y_deg } });
  }
  $('camera-form').addEventListener('submit', (e) => {
    e.preventDefault();
    if (!view.camera) return;
    const c = { position: [], target: [], up: view.camera.up, fov_y_deg: 0 };
    for (const [id, key, i] of CAM_FIELDS) {
      const raw = $(id).value.trim();
      const v = Number(raw);
      if (raw === '' || !isFinite(v)) { toast(`${$(id).getAttribute('aria-label')}: not a number`, 'error'); return; }
      if (i == null) c[key] = v; else c[key][i] = v;
    }
    sendCamera(c);
    document.activeElement?.blur();
  });

  // Bookmarks live in this browser (localStorage), one list per scene name.
  const bookmarkKey = () => `lightfold.bookmarks.${view.scene?.name || ''}`;
  function readBookmarks() {
    try {
      const v = JSON.parse(localStorage.getItem(bookmarkKey()) || '[]');
      return Array.isArray(v) ? v.filter((b) => b && typeof b.name === 'string' && b.camera) : [];
    } catch (e) { return []; }
  }
  function writeBookmarks(list) {
    try { localStorage.setItem(bookmarkKey(), JSON.stringify(list)); } catch (e) { toast(`cannot keep bookmarks: ${e.message}`, 'error'); }
    loadBookmarks();
  }
  function loadBookmarks() {
    const list = readBookmarks();
    view.bookmarks = list.map((b) => b.name);
    const ul = $('bookmarks');
    if (!list.length) { ul.replaceChildren(el('li', { class: 'dim', text: 'none' })); return; }
    ul.replaceChildren(...list.map((b) => el('li', {},
      el('button', { class: 'bname', title: 'go to this camera', onclick: () => sendCamera(b.camera) }, b.name),
      el('span', { class: 'mono dim', text: `${fmtVec(b.camera.position)} → ${fmtVec(b.camera.target)} · ${Number(b.camera.fov_y_deg).toFixed(1)}°` }),
      el('button', { title: 'delete this bookmark', 'aria-label': `delete ${b.name}`, onclick: () => writeBookmarks(readBookmarks().filter((x) => x.name !== b.name)) }, '×'))));
  }
  $('bookmark-form').addEventListener('submit', (e) => {
    e.preventDefault();
    if (!view.camera) return;
    const list = readBookmarks();
    const name = $('bookmark-name').value.trim() || `view ${list.length + 1}`;
    const c = view.camera;
    const entry = { name, camera: { position: c.position, target: c.target, up: c.up, fov_y_deg: c.fov_y_deg } };
    const i = list.findIndex((b) => b.name === name);
    if (i >= 0) list[i] = entry; else list.push(entry);
    $('bookmark-name').value = '';
    writeBookmarks(list);
  });

  // ---- exposure ---------------------------------------------------------------------------
  // Stops (EV): the view encodes frames at 2^stops × radiance; a change re-encodes the frame on
  // screen, no node renders again.
  const expo = { scene: 0, timer: null, last: 0 };
  const fmtEv = (x) => `${x >= 0 ? '+' : '−'}${Math.abs(x).toFixed(1)} EV`;
  function setupExposure(e) {
    expo.scene = typeof e.scene_stops === 'number' ? e.scene_stops : 0;
    const lo = Math.max(e.min ?? -8, Math.min(-8, Math.floor(expo.scene)));
    const hi = Math.min(e.max ?? 8, Math.max(8, Math.ceil(expo.scene)));
    $('exposure').min = String(lo);
    $('exposure').max = String(hi);
    showExposure(typeof e.stops === 'number' ? e.stops : expo.scene);
  }
  function showExposure(stops) {
    if (typeof stops !== 'number') return;
    view.exposure = stops;
    if (!expo.timer && document.activeElement !== $('exposure')) $('exposure').value = String(stops);
    $('exposure-label').textContent = fmtEv(stops);
  }
  // Throttled like the lights: at most one message per LIGHT_THROTTLE_MS, the last value sent.
  function sendExposure() {
    if (expo.timer) return;
    const go = () => {
      expo.timer = null;
      expo.last = performance.now();
      send({ type: 'exposure', stops: Number($('exposure').value) });
    };
    const wait = LIGHT_THROTTLE_MS - (performance.now() - expo.last);
    if (wait <= 0) go(); else expo.timer = setTimeout(go, wait);
  }
  $('exposure').addEventListener('input', () => {
    $('exposure-label').textContent = fmtEv(Number($('exposure').value));
    sendExposure();
  });
  $('exposure').addEventListener('dblclick', () => {
    $('exposure').value = String(expo.scene);
    $('exposure').dispatchEvent(new Event('input'));
  });

  // ---- lights -----------------------------------------------------------------------------
  // Per light: {index, color (linear), intensity, inputs, timer, last}.
  const controls = [];
  const publish = (st) => {
    const l = view.lights.find((x) => x.index === st.index);
    if (l) Object.assign(l, { color: st.color.slice(), intensity: st.intensity });
  };
  function buildLights(lights) {
    const box = $('lights');
    box.replaceChildren();
    controls.length = 0;
    view.lights = [];
    if (!lights.length) { box.append(el('div', { class: 'dim', text: 'the scene has no lights' })); return; }
    for (const l of lights) {
      const st = { index: l.index, color: (l.color || [1, 1, 1]).slice(), intensity: 1, timer: null, last: 0 };
      const color = el('input', { type: 'color', value: linearToHex(st.color), title: 'colour (sRGB; sent linear)' });
      const slider = el('input', { type: 'range', min: '0', max: '4', step: '0.05', value: '1', title: 'intensity multiplier' });
      const val = el('span', { class: 'mono val', text: '1.00×' });
      color.addEventListener('input', () => { st.color = hexToLinear(color.value); sendLight(st); });
      slider.addEventListener('input', () => {
        st.intensity = Number(slider.value);
        val.textContent = `${st.intensity.toFixed(2)}×`;
        sendLight(st);
      });
      slider.addEventListener('dblclick', () => { slider.value = '1'; slider.dispatchEvent(new Event('input')); });
      Object.assign(st, { colorInput: color, slider, val });
      controls.push(st);
      view.lights.push({ index: st.index, color: st.color, intensity: st.intensity });
      const meta = [l.kind, l.power != null ? `${Number(l.power).toPrecision(3)} W` : null, l.samples > 1 ? `${l.samples} samples` : null]
        .filter(Boolean).join(' · ');
      const row = el('div', { class: 'light' },
        color,
        el('div', { class: 'light-name' }, el('div', { text: l.name || `light ${l.index}` }), el('div', { class: 'dim small', text: meta })),
        slider, val);
      box.append(row);
      if (l.spec) {
        const editor = lightEditor(l);
        editor.hidden = true;
        const edit = el('button', { type: 'button', class: 'small', title: 'edit by numbers', text: '✎' });
        edit.addEventListener('click', () => { editor.hidden = !editor.hidden; });
        const remove = el('button', { type: 'button', class: 'small', title: 'remove this light', text: '✕' });
        remove.addEventListener('click', () => send({ type: 'light_remove', index: l.index }));
        row.append(edit, remove);
        box.append(editor);
      }
    }
  }

  // Numeric fields for every number of a light's [[light]] table (position, direction, size,
  // samples, …); a change sends the table as edited. The server checks it.
  function lightEditor(l) {
    const box = el('div', { class: 'light-edit' });
    const spec = l.spec;
    for (const [key, value] of Object.entries(spec)) {
      if (key === 'type' || key === 'name' || key === 'color') continue;
      const values = Array.isArray(value) ? value : typeof value === 'number' ? [value] : null;
      if (!values || !values.every((v) => typeof v === 'number')) continue;
      const cells = el('span', {});
      const inputs = values.map((v) => {
        const input = el('input', { type: 'number', step: 'any', value: String(v), 'aria-label': `${key}` });
        input.addEventListener('change', () => {
          const got = inputs.map((i) => Number(i.value));
          if (got.some((x) => !Number.isFinite(x))) { toast(`${key}: not a number`); return; }
          const next = Object.assign({}, spec, { [key]: Array.isArray(value) ? got : got[0] });
          send({ type: 'light_set', index: l.index, light: next });
        });
        return input;
      });
      cells.append(...inputs);
      box.append(el('label', { class: 'dim small', text: key }), cells);
    }
    return box;
  }

  // A new light at the camera's target, a fifth of the way to the camera and above it.
  $('light-add').addEventListener('submit', (e) => {
    e.preventDefault();
    const c = view.camera;
    if (!c) return;
    const at = c.target.map((t, i) => t + (c.position[i] - t) * 0.2 + (i === 1 ? 0.5 : 0));
    const dist = Math.hypot(...c.position.map((p, i) => p - c.target[i]));
    const size = Math.max(0.05, dist * 0.05);
    const down = [0, -1, 0];
    const specs = {
      sphere: { type: 'sphere', center: at, radius: size, radiance: 10 / (size * size) },
      rect: { type: 'rect', center: at, size: [2 * size, 2 * size], normal: down, u_axis: [1, 0, 0], radiance: 5 / (size * size) },
      disk: { type: 'disk', center: at, normal: down, radius: size, radiance: 5 / (size * size) },
      point: { type: 'point', position: at, intensity: 10 },
      spot: { type: 'spot', position: at, direction: down, intensity: 20, inner_angle_deg: 20, outer_angle_deg: 30 },
      directional: { type: 'directional', direction: [0.3, -1, -0.2], irradiance: 1 },
      sun: { type: 'directional', direction: [0.3, -1, -0.2], irradiance: 1, angle_deg: 2, samples: 16 },
      tube: { type: 'cylinder', center: at, axis: [1, 0, 0], length: 8 * size, radius: size / 4, radiance: 5 / (size * size) },
    };
    send({ type: 'light_add', light: specs[$('add-kind').value] });
  });

  // ---- light markers ----------------------------------------------------------------------
  // Each light with a position, projected with the camera onto the frame; dragging one moves
  // the light in the view's plane at its depth (`light_drag`, fractions of the view).
  const markers = $('markers');
  let lightDrag = null;
  function project(p) {
    const c = view.camera;
    const w = view.scene?.width;
    const h = view.scene?.height;
    if (!c || !w || !h) return null;
    const sub3 = (a, b) => a.map((x, i) => x - b[i]);
    const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    const cross3 = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    const norm3 = (a) => { const n = Math.hypot(...a) || 1; return a.map((x) => x / n); };
    const f = norm3(sub3(c.target, c.position));
    const r = norm3(cross3(f, c.up));
    const u = cross3(r, f);
    const d = sub3(p, c.position);
    const z = dot3(d, f);
    if (z <= 1e-6) return null;
    const t = Math.tan((c.fov_y_deg * Math.PI) / 360);
    return [dot3(d, r) / z / (t * (w / h)), dot3(d, u) / z / t];
  }
  function drawMarkers() {
    markers.replaceChildren();
    if (!view.canSteer || !img.style.width) return;
    const vr = $('viewport').getBoundingClientRect();
    const ir = img.getBoundingClientRect();
    for (const l of view.lightInfo || []) {
      if (!Array.isArray(l.position)) continue;
      const ndc = project(l.position);
      if (!ndc || Math.abs(ndc[0]) > 1.2 || Math.abs(ndc[1]) > 1.2) continue;
      const x = ir.left - vr.left + (ndc[0] * 0.5 + 0.5) * ir.width;
      const y = ir.top - vr.top + (0.5 - ndc[1] * 0.5) * ir.height;
      const m = el('div', { class: 'marker', title: `${l.name || `light ${l.index}`}: drag to move` });
      m.dataset.index = String(l.index);
      m.style.left = `${x}px`;
      m.style.top = `${y}px`;
      m.style.background = linearToHex(l.color || [1, 1, 1]);
      if (lightDrag && lightDrag.index === l.index) m.classList.add('active');
      m.addEventListener('mousedown', (e) => {
        if (e.button !== 0) return;
        e.preventDefault();
        e.stopPropagation();
        lightDrag = { index: l.index, x: e.clientX, y: e.clientY, dx: 0, dy: 0, queued: false };
        m.classList.add('active');
      });
      markers.append(m);
    }
  }
  // A drag of a light or an object: `d` gathers the pointer's moves as fractions of the frame
  // (`dx` right, `dy` up) and `flush` sends them, at most once per animation frame and once
  // more when the button is released.
  function addDragMove(d, e) {
    const r = img.getBoundingClientRect();
    d.dx += (e.clientX - d.x) / Math.max(1, r.width);
    d.dy -= (e.clientY - d.y) / Math.max(1, r.height);
    d.x = e.clientX;
    d.y = e.clientY;
  }
  function queueDrag(current, flush) {
    const d = current();
    if (d.queued) return;
    d.queued = true;
    requestAnimationFrame(() => {
      const now = current();
      if (!now) return;
      now.queued = false;
      flush();
    });
  }
  function sendLightDrag() {
    if (lightDrag && (lightDrag.dx || lightDrag.dy)) {
      send({ type: 'light_drag', index: lightDrag.index, x: lightDrag.dx, y: lightDrag.dy });
      lightDrag.dx = 0;
      lightDrag.dy = 0;
    }
  }
  window.addEventListener('mousemove', (e) => {
    if (!lightDrag) return;
    addDragMove(lightDrag, e);
    // The marker follows the pointer at once; the light follows in the frames.
    const m = markers.querySelector(`.marker[data-index="${lightDrag.index}"]`);
    if (m) {
      m.style.left = `${parseFloat(m.style.left) + e.movementX}px`;
      m.style.top = `${parseFloat(m.style.top) + e.movementY}px`;
    }
    queueDrag(() => lightDrag, sendLightDrag);
  });
  window.addEventListener('mouseup', () => {
    if (!lightDrag) return;
    sendLightDrag();
    lightDrag = null;
    drawMarkers();
  });

  // ---- objects ----------------------------------------------------------------------------
  // Alt+mousedown in the frame picks the object under the pointer (`object_pick`, answered by
  // `object`); dragging on moves it in the view's plane at its depth (`object_drag`). The form
  // sets its move by numbers (`object_set`); `moves` lists every object moved.
  let objDrag = null;
  view.moves = [];
  view.object = null;
  function fractionOf(e) {
    const r = img.getBoundingClientRect();
    return [(e.clientX - r.left) / Math.max(1, r.width), (e.clientY - r.top) / Math.max(1, r.height)];
  }
  vp.addEventListener('mousedown', (e) => {
    if (e.button !== 0 || !e.altKey || !view.canSteer) return;
    const [x, y] = fractionOf(e);
    if (x < 0 || x > 1 || y < 0 || y > 1) return;
    e.preventDefault();
    e.stopImmediatePropagation();
    objDrag = { mesh: null, x: e.clientX, y: e.clientY, dx: 0, dy: 0, queued: false };
    send({ type: 'object_pick', x, y }, false);
  }, true);
  function showObject(o) {
    view.object = o;
    const f = $('object-form');
    f.hidden = !o;
    if (!o) return;
    $('object-name').textContent = o.name || `object ${o.mesh}`;
    $('object-mesh').textContent = o.fixed ? `(mesh ${o.mesh}: ${o.fixed})` : `(mesh ${o.mesh})`;
    ['x', 'y', 'z'].forEach((a, i) => {
      $(`obj-t${a}`).value = String(o.translate[i]);
      $(`obj-r${a}`).value = String(o.rotate[i]);
    });
    $('obj-s').value = String(o.scale);
    for (const i of f.querySelectorAll('input, button')) i.disabled = !!o.fixed;
  }
  function onObject(o) {
    if (o.mesh === null || o.mesh === undefined) {
      objDrag = null;
      return toast('no object there', 'notice');
    }
    showObject(o);
    if (o.fixed) { objDrag = null; return toast(o.fixed, 'error'); }
    if (objDrag) objDrag.mesh = o.mesh;
  }
  function onMoves(moves) {
    view.moves = moves;
    const ul = $('moves');
    ul.replaceChildren();
    if (!moves.length) ul.append(el('li', { class: 'dim', text: 'no object moved' }));
    for (const m of moves) {
      const li = el('li', { text: `${m.name || `object ${m.mesh}`} · move ${m.translate.map((v) => v.toFixed(2)).join(', ')} · turn ${m.rotate.map((v) => v.toFixed(0)).join(', ')}° · ×${m.scale}` });
      li.addEventListener('click', () => showObject(m));
      ul.append(li);
    }
    // The form shows the selected object's move as it is now.
    const o = view.object;
    if (o && !(objDrag && objDrag.mesh === o.mesh)) {
      const now = moves.find((m) => m.mesh === o.mesh);
      showObject(now || { ...o, translate: [0, 0, 0], rotate: [0, 0, 0], scale: 1 });
    }
  }
  function sendObjectDrag() {
    if (objDrag && objDrag.mesh !== null && (objDrag.dx || objDrag.dy)) {
      send({ type: 'object_drag', mesh: objDrag.mesh, x: objDrag.dx, y: objDrag.dy });
      objDrag.dx = 0;
      objDrag.dy = 0;
    }
  }
  window.addEventListener('mousemove', (e) => {
    if (!objDrag) return;
    addDragMove(objDrag, e);
    queueDrag(() => objDrag, sendObjectDrag);
  });
  window.addEventListener('mouseup', () => {
    if (!objDrag) return;
    sendObjectDrag();
    objDrag = null;
  });
  $('object-form').addEventListener('submit', (e) => {
    e.preventDefault();
    const o = view.object;
    if (!o) return;
    const num = (id) => Number($(id).value);
    send({
      type: 'object_set', mesh: o.mesh,
      translate: ['x', 'y', 'z'].map((a) => num(`obj-t${a}`)),
      rotate: ['x', 'y', 'z'].map((a) => num(`obj-r${a}`)),
      scale: num('obj-s'),
    });
  });
  // Keys for the selected object: Q/E turn it 15° about the vertical, [ and ] scale it by
  // 1/1.1 and 1.1.
  function turnOrScaleObject(k) {
    const o = view.object;
    if (!o || o.fixed) return false;
    const now = view.moves.find((m) => m.mesh === o.mesh) || { translate: [0, 0, 0], rotate: [0, 0, 0], scale: 1 };
    const rotate = [...now.rotate];
    let scale = now.scale;
    if (k === 'q') rotate[1] += 15;
    else if (k === 'e') rotate[1] -= 15;
    else if (k === ']') scale *= 1.1;
    else scale /= 1.1;
    rotate[1] = ((rotate[1] + 540) % 360) - 180;
    send({ type: 'object_set', mesh: o.mesh, translate: now.translate, rotate, scale });
    return true;
  }
  $('obj-back').addEventListener('click', () => {
    if (view.object) send({ type: 'object_set', mesh: view.object.mesh });
  });

  // Throttled: at most one message per light per LIGHT_THROTTLE_MS, the last value always sent.
  function sendLight(st) {
    const now = performance.now();
    const go = () => {
      st.timer = null;
      st.last = performance.now();
      publish(st);
      send({ type: 'light', index: st.index, color: st.color, intensity: st.intensity });
    };
    if (st.timer) return;
    const wait = LIGHT_THROTTLE_MS - (now - st.last);
    if (wait <= 0) go();
    else st.timer = setTimeout(go, wait);
  }

  // The lights message carries each light whole (kind, samples, position, its [[light]] table):
  // a light added, removed or reshaped rebuilds the list; a colour alone updates it.
  let lightsShape = '';
  function onLights(lights) {
    view.lightInfo = lights;
    const shape = JSON.stringify(lights.map((l) => [l.name, l.kind, l.power, l.samples, l.spec]));
    if (shape !== lightsShape) {
      lightsShape = shape;
      if (!controls.some((s) => s.timer)) buildLights(lights);
    }
    drawMarkers();
    for (const l of lights) {
      const st = controls.find((s) => s.index === l.index);
      if (!st || st.timer) continue; // a change of ours is on its way
      if (Array.isArray(l.color)) { st.color = l.color.slice(); st.colorInput.value = linearToHex(st.color); }
      if (typeof l.intensity === 'number') {
        st.intensity = l.intensity;
        if (document.activeElement !== st.slider) st.slider.value = String(l.intensity);
        st.val.textContent = `${l.intensity.toFixed(2)}×`;
      }
      publish(st);
    }
  }

  // ---- timings ----------------------------------------------------------------------------
  $('legend').append(...SEGMENTS.map(([name], i) => el('span', { class: 'key' }, el('i', { class: `seg s${i}` }), name)));
  let timingsQueued = null;
  function scheduleTimings(h) {
    if (timingsQueued) { timingsQueued = h; return; }
    timingsQueued = h;
    requestAnimationFrame(() => { const x = timingsQueued; timingsQueued = null; showTimings(x); });
  }

  function showTimings(h) {
    const order = (d) => (d.role === 'node' ? 0 : 1);
    const ds = (h.daemons || []).slice().sort((a, b) => order(a) - order(b) || String(a.id).localeCompare(String(b.id), undefined, { numeric: true }));
    const box = $('timings');
    if (!ds.length) { box.replaceChildren(el('div', { class: 'dim', text: 'no timings in this frame' })); return; }
    const sum = (d) => SEGMENTS.reduce((a, [, k]) => a + (d[k] || 0), 0);
    const scale = Math.max(1, ...ds.map((d) => Math.max(sum(d), d.total_us || 0)));
    const rows = ds.map((d) => {
      const bar = el('div', { class: 'bar' });
      SEGMENTS.forEach(([name, k], i) => {
        const v = d[k] || 0;
        if (v <= 0) return;
        bar.append(el('i', { class: `seg s${i}`, style: `width:${(100 * v / scale).toFixed(2)}%`, title: `${name} ${ms(v / 1000)}` }));
      });
      const parts = SEGMENTS.filter(([, k]) => d[k] > 0).map(([name, k]) => `${name} ${ms(d[k] / 1000)}`).join(' · ');
      const extra = [d.role === 'node' && d.lights_rendered != null ? `${d.lights_rendered} lights` : null,
        d.bytes_out != null ? `${bytes(d.bytes_out)} out` : null].filter(Boolean).join(' · ');
      return el('div', { class: `trow ${d.role}` },
        el('div', { class: 'tname', title: `${d.id} (${d.role})` }, el('b', { text: d.id })),
        bar,
        el('div', { class: 'tms mono', text: ms((d.total_us || sum(d)) / 1000) }),
        el('div', { class: 'tparts dim small', text: [parts, extra].filter(Boolean).join('  |  ') }));
    });
    box.replaceChildren(...rows);
    $('timing-total').textContent = `frame ${h.frame} · ${bytes(h.jpeg_bytes)} JPEG · ${bytes(h.sink_bytes)} at the sink`;
  }

  // ---- plan graph -------------------------------------------------------------------------
  let planKey = '';
  function showPlan(plan) {
    const key = JSON.stringify(plan || null);
    if (key === planKey) return;
    planKey = key;
    const box = $('plan');
    if (!plan || !plan.nodes) { box.replaceChildren(el('div', { class: 'dim', text: 'no plan yet' })); return; }
    const budget = plan.frame_budget_ms != null ? ` · budget ${ms(plan.frame_budget_ms)}` : '';
    $('plan-summary').textContent = `K ${plan.k ?? '–'} · ${plan.samples ?? '–'} samples · est. ${ms(plan.est_frame_ms)}/frame${budget}`;
    const gave = [plan.gave_up, plan.penumbra, plan.peels, plan.decomposition, plan.partition].filter(Boolean).join(' · ');
    $('gave-up').hidden = !gave;
    $('gave-up').textContent = gave;
    const items = new Map(); // id -> {kind, col, lines}
    for (const n of plan.nodes) {
      const lights = Array.isArray(n.lights) ? n.lights.length : n.lights;
      const part = (n.part != null ? ` · part ${n.part}` : '') + (n.tile != null ? ` · tile ${n.tile}` : '');
      items.set(n.id, { kind: 'node', col: 0, lines: [n.id, `${lights} light${lights === 1 ? '' : 's'}${part}${n.est_ms != null ? ` · ${ms(n.est_ms)}` : ''}`], color: n.color });
    }
    for (const s of plan.stages || []) items.set(s.id, { kind: 'stage', col: 1, lines: [s.id, (s.ops || []).join(' + ')] });
    // Whatever no node or stage is called is the sink ("sink", or the sink's address).
    const sink = ' sink';
    items.set(sink, { kind: 'sink', col: 2, lines: ['sink', plan.sink != null && plan.sink !== 'sink' ? String(plan.sink) : 'coordinator'] });
    let links = plan.links || [];
    if (!links.length) {
      links = [...plan.nodes, ...(plan.stages || [])].filter((x) => x.downstream != null).map((x) => ({ from: x.id, to: x.downstream }));
    }
    links = links.map((l) => (items.has(l.to) && l.to !== sink ? l : { ...l, to: sink }));
    // Stages feeding stages go further right: column = longest path from the nodes.
    for (let pass = 0; pass < items.size; pass++) {
      let moved = false;
      for (const l of links) {
        const a = items.get(l.from); const b = items.get(l.to);
        if (a && b && b.kind !== 'node' && b.col <= a.col) { b.col = a.col + 1; moved = true; }
      }
      if (!moved) break;
    }
    const last = Math.max(...[...items.values()].filter((x) => x.kind !== 'sink').map((x) => x.col)) + 1;
    items.get(sink).col = Math.max(last, 2);
    const BW = 132, BH = 44, GAP = 150, CW = BW + GAP, RH = 62, PAD = 12;
    let W, H;
    if (items.get(sink).col <= 3) {
      // Shallow: one column per step from the nodes.
      const cols = [];
      for (const [id, it] of items) (cols[it.col] ||= []).push(id);
      const rows = Math.max(...cols.map((c) => (c ? c.length : 0)));
      H = rows * RH + PAD * 2; W = (cols.length - 1) * CW + BW + PAD * 2;
      cols.forEach((ids, c) => (ids || []).forEach((id, r) => {
        const it = items.get(id);
        it.x = PAD + c * CW;
        it.y = PAD + (H - PAD * 2 - ids.length * RH) / 2 + r * RH + (RH - BH) / 2;
      }));
    } else {
      // Deep (a chain of many stages, a tall tree): three columns, the stages stacked in order
      // from the nodes, each beside the nodes that feed it, stage-to-stage links on the right.
      const stageIds = [...items.keys()].filter((id) => items.get(id).kind === 'stage');
      stageIds.sort((a, b) => items.get(a).col - items.get(b).col || a.localeCompare(b, undefined, { numeric: true }));
      const feeds = (id) => links.filter((l) => l.to === id && items.get(l.from)?.kind === 'node').map((l) => l.from);
      let row = 0;
      const placed = new Set();
      for (const id of stageIds) {
        const fed = feeds(id).filter((n) => !placed.has(n));
        fed.forEach((n, i) => { const it = items.get(n); it.col = 0; it.row = row + i; placed.add(n); });
        const st = items.get(id);
        st.col = 1; st.row = row + (Math.max(fed.length, 1) - 1) / 2;
        row += Math.max(fed.length, 1);
      }
      for (const [id, it] of items) if (it.kind === 'node' && !placed.has(id)) { it.col = 0; it.row = row++; }
      const lastStage = stageIds.length ? items.get(stageIds[stageIds.length - 1]).row : 0;
      Object.assign(items.get(sink), { col: 2, row: lastStage });
      H = Math.max(row, 1) * RH + PAD * 2; W = 2 * CW + BW + PAD * 2;
      for (const it of items.values()) { it.x = PAD + it.col * CW; it.y = PAD + it.row * RH + (RH - BH) / 2; }
    }
    const root = svg('svg', { viewBox: `0 0 ${W} ${H}`, width: W, height: H, style: 'max-width:100%;height:auto', role: 'img', 'aria-label': 'the plan' });
    root.append(svg('defs', {}));
    root.firstChild.innerHTML = '<marker id="arrow" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="6" markerHeight="6" orient="auto"><path d="M0,0 L10,5 L0,10 z" fill="#7d8aa5"/></marker>';
    for (const l of links) {
      const a = items.get(l.from), b = items.get(l.to);
      if (!a || !b) continue;
      if (a.x === b.x) {
        // Stacked stages: a loop on the right from one to the next; its label beside it.
        const x = a.x + BW, ya = a.y + BH / 2, yb = b.y + BH / 2, out = x + 36;
        root.append(svg('path', { d: `M${x},${ya} C${out},${ya} ${out},${yb} ${x},${yb}`, class: 'edge', 'marker-end': 'url(#arrow)' }));
        const label = svg('text', { x: out + 4, y: (ya + yb) / 2 + 3, class: 'elabel' }, l.bytes_per_frame != null ? `${bytes(l.bytes_per_frame)}/frame` : '');
        label.append(svg('title', {}, `${l.from} → ${b.lines[0]}\n${(l.layers || []).join(', ')}`));
        root.append(label);
        continue;
      }
      const x1 = a.x + BW, y1 = a.y + BH / 2, x2 = b.x, y2 = b.y + BH / 2, mx = (x1 + x2) / 2;
      root.append(svg('path', { d: `M${x1},${y1} C${mx},${y1} ${mx},${y2} ${x2},${y2}`, class: 'edge', 'marker-end': 'url(#arrow)' }));
      const layers = (l.layers || []).join(', ');
      // The label sits over the edge's midpoint, its layers wrapped to the gap's width.
      const lines = [];
      for (const name of l.layers || []) {
        if (lines.length && (lines[lines.length - 1] + ', ' + name).length <= 24) lines[lines.length - 1] += ', ' + name;
        else lines.push(name);
      }
      if (lines.length > 3) lines.splice(2, lines.length, `+${(l.layers || []).length - lines.slice(0, 2).join(', ').split(', ').length} more`);
      // On the curve, early in its first gap (so labels of converging edges stay apart).
      const bz = (t, a, b, c, d) => (1 - t) ** 3 * a + 3 * (1 - t) ** 2 * t * b + 3 * (1 - t) * t * t * c + t ** 3 * d;
      let lo = 0, hi = 1;
      for (let i = 0; i < 20; i++) { const m = (lo + hi) / 2; if (bz(m, x1, mx, mx, x2) < x1 + GAP * 0.45) lo = m; else hi = m; }
      const tx = bz(lo, x1, mx, mx, x2), ty = bz(lo, y1, y1, y2, y2) - 6 * lines.length;
      const label = svg('text', { x: tx, y: ty, class: 'elabel', 'text-anchor': 'middle' });
      lines.forEach((t, i) => label.append(svg('tspan', { x: tx, dy: i ? 11 : 0 }, t)));
      if (l.bytes_per_frame != null) label.append(svg('tspan', { x: tx, dy: lines.length ? 11 : 0, class: 'ebytes' }, `${bytes(l.bytes_per_frame)}/frame`));
      const t = svg('title', {}, `${l.from} → ${b.lines[0]}\n${layers}\n${bytes(l.bytes_per_frame)} per frame`);
      label.append(t);
      root.append(label);
    }
    for (const [id, it] of items) {
      const g = svg('g', { class: `box ${it.kind}` });
      g.append(svg('rect', { x: it.x, y: it.y, width: BW, height: BH, rx: 6 }));
      const fit = (t, n) => (t.length > n ? `${t.slice(0, n - 1)}…` : t);
      g.append(svg('title', {}, it.lines.join('\n') + (it.color != null ? `\ncolour group ${JSON.stringify(it.color)}` : '')));
      g.append(svg('text', { x: it.x + BW / 2, y: it.y + 18, 'text-anchor': 'middle', class: 'bname' }, fit(it.lines[0], 18)));
      g.append(svg('text', { x: it.x + BW / 2, y: it.y + 34, 'text-anchor': 'middle', class: 'bsub' }, fit(it.lines[1], 24)));
      root.append(g);
    }
    box.replaceChildren(root);
  }

  // ---- cluster state ----------------------------------------------------------------------
  function showStatus(s) {
    const st = $('state');
    st.textContent = s.state || '–';
    st.className = `pill state-${s.state}`;
    const kv = $('cluster');
    kv.replaceChildren();
    const row = (k, v) => kv.append(el('dt', { text: k }), el('dd', { text: v }));
    row('state', s.state ?? '–');
    row('epoch', s.epoch == null ? '–' : `${epochLabel(s.epoch)} (${s.epoch})`);
    row('viewers', s.viewers ?? '–');
    if (s.plan) {
      row('nodes / stages', `${(s.plan.nodes || []).length} / ${(s.plan.stages || []).length}`);
      row('lights per node (K)', s.plan.k ?? '–');
      if (s.plan.partitions) row('sort-last parts', s.plan.partitions);
    }
    const list = (id, items, f) => {
      const ul = $(id);
      ul.replaceChildren(...(items && items.length ? items.map(f) : [el('li', { class: 'dim', text: 'none' })]));
    };
    list('lost', s.lost, (l) => el('li', { class: 'bad' }, el('b', { text: l.id }), ` — ${l.reason}`));
    list('incidents', (s.incidents || []).slice(-12).reverse(), (i) =>
      el('li', {}, el('span', { class: 'mono dim', text: `${Number(i.at_s).toFixed(1)} s ` }), el('b', { text: i.daemon ?? '' }), ` ${i.text}`));
    const tb = $('epochs').tBodies[0];
    tb.replaceChildren(...(s.epochs || []).map((e, i) => el('tr', { title: `epoch ${e.epoch}` },
      ...[`#${i + 1}`, `${Number(e.at_s).toFixed(1)} s`, e.reason, e.nodes, e.stages, e.k, e.lights_moved, ms(e.configure_ms)]
        .map((v) => el('td', { text: v ?? '–' })))).reverse());
    showPlan(s.plan);
  }

  // ---- notices ----------------------------------------------------------------------------
  // Shown for NOTICE_MS; a repeat of a message on screen extends it instead of stacking.
  function toast(text, kind) {
    let t = [...$('toasts').children].find((x) => x.textContent === text);
    if (!t) { t = el('div', { class: `toast ${kind}`, text }); $('toasts').append(t); }
    clearTimeout(t.fadeTimer);
    clearTimeout(t.removeTimer);
    t.classList.remove('fade');
    t.fadeTimer = setTimeout(() => t.classList.add('fade'), NOTICE_MS - 600);
    t.removeTimer = setTimeout(() => t.remove(), NOTICE_MS);
  }
  function log(text) {
    const ul = $('log');
    ul.prepend(el('li', {}, el('span', { class: 'mono dim', text: `${new Date().toLocaleTimeString()} ` }), text));
    while (ul.children.length > 100) ul.lastChild.remove();
  }

  img.style.visibility = 'hidden';
  connect();
})();
