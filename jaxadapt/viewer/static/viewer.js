// jaxadapt view: draw the server's frames, send the pointer as the gaze.
"use strict";
(function () {
  const canvas = document.getElementById("view");
  const context = canvas.getContext("2d");
  const overlay = document.getElementById("overlay");
  const message = document.getElementById("message");
  const status = document.getElementById("status");
  const state = {
    frames: 0, header: null, size: [16, 9], paused: false, effects: [], resets: 0, trackers: 0,
    lsl: null, errors: [], seen: [], closed: null,
    // this page's gaze ids: numbers from a random base, so that two pages' ids differ
    gazeId: 1e4 * Math.floor(Math.random() * 1e9),
    latencies: [], // ms from a pointer's gaze sent to the frame that uses it drawn, the last 600
  };
  const firstId = state.gazeId + 1;
  const sentAt = new Map(); // this page's gaze ids not yet seen in a frame: their performance.now()
  window.jaxadapt = state; // for tests and the curious
  const url = new URL("ws", location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  url.search = location.search; // the token, where one is needed
  const socket = new WebSocket(url);
  socket.binaryType = "arraybuffer";
  let pending = 0; // frames drawn but not acknowledged while the tab is hidden

  function send(object) {
    if (socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(object));
  }

  function ack() {
    if (document.hidden) { pending += 1; return; } // a hidden tab asks for nothing
    send({ type: "ack" });
  }

  document.addEventListener("visibilitychange", function () {
    while (!document.hidden && pending > 0) { pending -= 1; send({ type: "ack" }); }
  });

  function fit() {
    const [w, h] = state.size;
    const scale = Math.min((innerWidth - 16) / w, (innerHeight - 90) / h);
    canvas.style.width = Math.max(1, Math.floor(w * scale)) + "px";
    canvas.style.height = Math.max(1, Math.floor(h * scale)) + "px";
  }
  addEventListener("resize", fit);

  function effectBoxes(available) {
    const box = document.getElementById("effects");
    box.textContent = "";
    available.forEach(function (name, i) {
      const label = document.createElement("label");
      const input = document.createElement("input");
      input.type = "checkbox";
      input.id = "effect-" + name;
      input.addEventListener("change", function () {
        send({ type: "effect", name: name, on: input.checked });
      });
      label.append(input, " " + (i + 1) + " " + name.replace("_", " "));
      box.append(label);
    });
    document.getElementById("effects-help").hidden = available.length === 0;
    document.getElementById("effects-last").textContent = String(available.length);
  }

  // The view's state as the server tells every page (hello, then each
  // change from any page): pause, effects, resets, trackers (and the LSL
  // stream's name where one drives the gaze).
  function show(m) {
    state.paused = m.paused;
    state.effects = m.effects;
    state.resets = m.resets;
    state.trackers = m.trackers;
    state.lsl = m.lsl;
    document.getElementById("pause").textContent = state.paused ? "resume" : "pause";
    document.querySelectorAll("#effects input").forEach(function (input) {
      input.checked = state.effects.includes(input.id.slice("effect-".length));
    });
    describe();
  }

  // The overlay (frame rate, adaptation, time) and the status line (the
  // server stopped, a tracker driving the gaze, simulated time lagging).
  function describe() {
    const header = state.header;
    status.className = state.closed === null ? "" : "stopped";
    if (state.closed !== null) {
      status.textContent = state.closed;
      overlay.textContent = state.closed + (header === null ? "" : "\nlast frame " + header.frame);
      return;
    }
    const notes = [];
    if (state.trackers > 0) {
      const which = state.lsl === null
        ? "an eye tracker" : "the eye tracker of LSL stream \"" + state.lsl + "\"";
      notes.push(which + " drives the gaze: the pointer is ignored");
    }
    if (header !== null && header.slow && !state.paused) {
      const slow = header.slow;
      notes.push(
        "simulated time runs at " + Math.round(100 * slow.max_dt / slow.frame_time) +
        " % of real time (" + header.lag.toFixed(1) + " s behind): a frame takes " +
        slow.frame_time.toFixed(2) + " s here and advances it at most " + slow.max_dt +
        " s; a smaller --size keeps up");
    }
    status.textContent = notes.join("; ");
    if (header === null) { overlay.textContent = state.paused ? "paused" : "connecting..."; return; }
    const a = header.adaptation;
    const latency = medianLatency();
    overlay.textContent =
      (state.paused ? "paused" : header.fps.toFixed(0) + " frames/s") + "  frame " + header.frame +
      (latency === null ? "" : "  gaze to frame " + latency.toFixed(0) + " ms") +
      "\nadapted to " + (a >= 100 || a < 0.01 ? a.toExponential(2) : a.toFixed(2)) + " cd/m2\n" +
      "t = " + header.t.toFixed(2) + " s";
  }

  // Gaze-to-frame latency: each of this page's gaze samples up to the one
  // a frame used, from its sending to the next animation frame after the
  // frame is drawn (when the browser paints it). Frames that follow another
  // page's pointer or a tracker measure nothing; a tracker's samples
  // supersede this page's.
  function measure(used) {
    if (state.trackers > 0) { sentAt.clear(); return; }
    if (typeof used !== "number" || used < firstId || used > state.gazeId) return;
    requestAnimationFrame(function () {
      const shown = performance.now();
      for (const [id, sent] of sentAt) {
        if (id > used) break; // (a Map keeps the order ids were sent in)
        state.latencies.push(shown - sent);
        sentAt.delete(id);
      }
      if (state.latencies.length > 600) state.latencies.splice(0, state.latencies.length - 600);
    });
  }

  function medianLatency() {
    const last = state.latencies.slice(-60).sort(function (a, b) { return a - b; });
    return last.length === 0 ? null : last[Math.floor((last.length - 1) / 2)];
  }

  async function draw(buffer) {
    const length = new DataView(buffer).getUint32(0);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
    const blob = new Blob([new Uint8Array(buffer, 4 + length)], { type: "image/jpeg" });
    const bitmap = await createImageBitmap(blob);
    if (state.closed !== null) { bitmap.close(); return; } // (closed while it decoded)
    if (state.header !== null && header.frame < state.header.frame) {
      bitmap.close(); // decoded after a newer frame (decodes may finish out of order)
      ack();
      return;
    }
    context.drawImage(bitmap, 0, 0);
    bitmap.close();
    measure(header.gaze_id);
    state.frames += 1;
    state.header = header;
    state.seen.push([header.frame, header.digest]); // the last frames drawn, for tests
    if (state.seen.length > 300) state.seen.shift();
    describe();
    ack();
  }

  socket.addEventListener("message", function (event) {
    if (typeof event.data !== "string") { draw(event.data); return; }
    const m = JSON.parse(event.data);
    if (m.type === "hello") {
      state.size = m.size;
      canvas.width = m.size[0];
      canvas.height = m.size[1];
      fit();
      effectBoxes(m.available_effects);
      show(m);
    } else if (m.type === "state") {
      show(m);
    } else if (m.type === "error" || m.type === "warning") {
      state.errors.push(m.message);
      message.textContent = m.type + ": " + m.message;
    } else if (m.type === "clear") { // the warning shown no longer applies
      if (message.textContent.startsWith("warning: ")) message.textContent = "";
    }
  });
  socket.addEventListener("close", function (event) {
    state.closed = event.code === 1001 && event.reason === "server stopped"
      ? "the server stopped: start jaxadapt view again, then reload this page"
      : "disconnected (" + event.code + (event.reason ? " " + event.reason : "") + "): reload this page";
    canvas.classList.add("stopped");
    describe();
  });

  // The canvas's area in frame pixels, whose centres are whole numbers: from
  // -0.5 at its left or top edge to W - 0.5 at its right or bottom edge.
  function framePixel(client, start, extent, pixels) {
    const x = (client - start) / extent * pixels - 0.5;
    return Math.min(Math.max(x, -0.5), pixels - 0.5);
  }

  canvas.addEventListener("pointermove", function (event) {
    const rect = canvas.getBoundingClientRect();
    const x = framePixel(event.clientX, rect.left, rect.width, canvas.width);
    const y = framePixel(event.clientY, rect.top, rect.height, canvas.height);
    state.gazeId += 1;
    const now = performance.now();
    if (sentAt.size > 1000) sentAt.delete(sentAt.keys().next().value); // (while paused)
    sentAt.set(state.gazeId, now);
    send({ type: "gaze", x: x, y: y, id: state.gazeId, t: now / 1000 });
  });

  function pause() { // (the server tells every page, this one included)
    send({ type: "pause", paused: !state.paused });
  }
  document.getElementById("pause").addEventListener("click", pause);
  document.getElementById("reset").addEventListener("click", function () { send({ type: "reset" }); });
  addEventListener("keydown", function (event) {
    if (event.key === " ") { pause(); event.preventDefault(); }
    else if (event.key === "r") send({ type: "reset" });
    else if (/^[1-9]$/.test(event.key)) {
      const input = document.querySelectorAll("#effects input")[Number(event.key) - 1];
      if (input) input.click();
    }
  });
})();
