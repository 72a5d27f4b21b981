// jaxadapt experiment: runs the trials the server plans, one display frame
// at a time (requestAnimationFrame), and posts each answer before the next.
// The page's state is on <body>: data-phase, and while an image is up
// data-stimulus (standard or test) and data-luminance (cd/m2).
"use strict";

const query = location.search; // ?token=... off loopback
const url = (path) => path + query;
const body = document.body;
const text = document.getElementById("text");
const canvas = document.getElementById("screen");
const ctx = canvas.getContext("2d", { alpha: false });
const FIXATION_MS = 500;
let setup = null;

function phase(name, stimulus, luminance) {
  body.dataset.phase = name;
  if (stimulus) {
    body.dataset.stimulus = stimulus;
    body.dataset.luminance = String(luminance);
  } else {
    delete body.dataset.stimulus;
    delete body.dataset.luminance;
  }
}

function say(words) {
  text.textContent = words || "";
}

function resize() {
  const r = window.devicePixelRatio || 1;
  canvas.width = Math.round(innerWidth * r);
  canvas.height = Math.round(innerHeight * r);
  canvas.style.width = innerWidth + "px";
  canvas.style.height = innerHeight + "px";
  clear();
}

function clear() {
  ctx.fillStyle = "#000";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
}

// Images are drawn at one image pixel per device pixel, centred.
function drawImage(bitmap) {
  const [w, h] = setup.size;
  ctx.drawImage(bitmap, Math.floor((canvas.width - w) / 2), Math.floor((canvas.height - h) / 2));
}

function drawFixation() {
  const f = setup.fixation;
  const x = Math.floor(canvas.width / 2) + f.x;
  const y = Math.floor(canvas.height / 2) + f.y;
  const t = Math.max(1, Math.round(f.size / 8));
  const half = Math.floor(f.size / 2);
  ctx.fillStyle = `rgb(${f.code},${f.code},${f.code})`;
  ctx.fillRect(x - half, y - Math.floor(t / 2), f.size, t);
  ctx.fillRect(x - Math.floor(t / 2), y - half, t, f.size);
}

const frame = () => new Promise((resolve) => requestAnimationFrame(resolve));
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

// Resolves with [value, time] at the first key of `keys` (key name -> value).
function key(keys) {
  return new Promise((resolve) => {
    function on(event) {
      if (event.repeat || !(event.key in keys)) return;
      event.preventDefault();
      removeEventListener("keydown", on);
      resolve([keys[event.key], performance.now()]);
    }
    addEventListener("keydown", on);
  });
}

// JSON from the server; while it cannot be reached (stopped, restarted),
// the page says so and tries again every second.
async function request(path, options) {
  for (let tries = 0; ; tries++) {
    try {
      const response = await fetch(url(path), options);
      if (response.ok) {
        if (tries) say("");
        return await response.json();
      }
      say(`The server refused: ${response.status} ${await response.text()}`);
    } catch (error) {
      say("Waiting for the server\u2026");
    }
    await sleep(1000);
  }
}

async function images(keys) {
  const unique = [...new Set(keys)];
  const bitmaps = await Promise.all(
    unique.map(async (k) => {
      for (;;) {
        try {
          const response = await fetch(url("/image/" + k));
          if (response.ok) return await createImageBitmap(await response.blob());
        } catch (error) {}
        say("Waiting for the server\u2026");
        await sleep(1000);
      }
    }),
  );
  return new Map(unique.map((k, i) => [k, bitmaps[i]]));
}

// The median time between display frames over `n` of them, ms.
async function framePeriod(n) {
  const stamps = [];
  for (let i = 0; i <= n; i++) stamps.push(await frame());
  const deltas = stamps.slice(1).map((t, i) => t - stamps[i]).sort((a, b) => a - b);
  return deltas[Math.floor(deltas.length / 2)];
}

async function instructions() {
  phase("instructions");
  say(`${setup.instructions}\n\n${setup.keys}`);
  const period = await framePeriod(30);
  const check = () => warn(period);
  check();
  addEventListener("resize", check);
  await key({ " ": true });
  removeEventListener("resize", check);
  // Full screen where the browser allows it (a key press may ask for it);
  // the trials begin once the window has its new size.
  if (document.documentElement.requestFullscreen) {
    await document.documentElement.requestFullscreen().catch(() => {});
    await frame();
  }
  say("");
}

// The instructions, with what would keep the images from being shown as
// planned: another frame rate than the display file's, a window smaller
// than the images.
function warn(period) {
  const problems = [];
  const measured = 1000 / period;
  if (Math.abs(measured - setup.refresh_hz) > 0.03 * setup.refresh_hz) {
    problems.push(
      `This display shows ${measured.toFixed(1)} frames/s; the display file says ` +
        `${setup.refresh_hz}: images would not last as planned.`,
    );
  }
  const [w, h] = setup.size;
  if (canvas.width < w || canvas.height < h) {
    problems.push(
      `The window is ${canvas.width}x${canvas.height} pixels, smaller than the images ` +
        `(${w}x${h}): make it full screen (F11) or larger.`,
    );
  }
  say([`${setup.instructions}\n\n${setup.keys}`, ...problems].join("\n\n"));
}

async function dark(seconds) {
  phase("dark");
  const end = performance.now() + 1000 * seconds;
  for (;;) {
    const left = Math.ceil((end - performance.now()) / 1000);
    if (left <= 0) break;
    say(`${Math.floor(left / 60)}:${String(left % 60).padStart(2, "0")}`);
    await sleep(250);
  }
  await pause("Press space to begin.");
}

async function pause(words) {
  phase("break");
  say(words);
  await key({ " ": true });
  say("");
}

// One trial: the fixation target while its images load, then both
// intervals as one run of display frames, then the answer.
async function trial(state) {
  // The cross, drawn every frame (a resize clears the canvas), for
  // FIXATION_MS and until the trial's images are loaded.
  phase("fixation");
  const intervals = state.intervals;
  let bitmaps = null;
  images(intervals.flatMap((i) => i.images)).then((loaded) => (bitmaps = loaded));
  const start = await frame();
  for (let now = start; bitmaps === null || now - start < FIXATION_MS; now = await frame()) {
    clear();
    drawFixation();
  }
  // Frame by frame: what to draw, and where each phase starts.
  const draws = [];
  const starts = [];
  intervals.forEach((interval, n) => {
    let shown = 0;
    interval.images.forEach((k, i) => {
      if (i === 0) starts.push([draws.length, "interval" + (n + 1), interval]);
      if (i === interval.shown) starts.push([draws.length, "blank" + (n + 1), null]);
      for (let h = 0; h < interval.holds[i]; h++) {
        draws.push({ image: bitmaps.get(k), shown: i < interval.shown });
      }
      if (i < interval.shown) shown += interval.holds[i];
    });
  });
  const stamps = [];
  let next = 0;
  for (let f = 0; f <= draws.length; f++) {
    stamps.push(await frame());
    if (f === draws.length) {
      clear();
      phase("respond");
      break;
    }
    clear(); // (every frame: a resize would have cleared the canvas)
    drawImage(draws[f].image);
    while (next < starts.length && starts[next][0] === f) {
      const [, name, interval] = starts[next++];
      if (interval) phase(name, interval.stimulus, interval.luminance);
      else phase(name);
    }
  }
  // What was shown, as the page timed it: each phase from the frame its
  // first image was drawn for to the frame the next was.
  const at = (i) => stamps[starts[i][0]];
  const durations = [at(1) - at(0), at(3) - at(2), at(2) - at(1), stamps[draws.length] - at(3)];
  const period = 1000 / setup.refresh_hz;
  let dropped = 0;
  for (let f = 0; f < draws.length; f++) {
    if (draws[f].shown && stamps[f + 1] - stamps[f] > 1.5 * period) dropped++;
  }
  for (const bitmap of bitmaps.values()) bitmap.close();
  const onset = stamps[draws.length];
  const [answer, time] = await key({ 1: 1, 2: 2, ArrowLeft: 1, ArrowRight: 2 });
  const reply = await request("/answer", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({
      trial: state.trial,
      answer: answer,
      rt_ms: time - onset,
      durations: durations,
      dropped: dropped,
    }),
  });
  return reply.next;
}

async function run() {
  resize();
  addEventListener("resize", resize);
  setup = await request("/session");
  text.style.color = `rgb(${setup.text_code},${setup.text_code},${setup.text_code})`;
  await instructions();
  if (setup.dark_seconds > 0) await dark(setup.dark_seconds);
  let state = await request("/next");
  while (state.phase === "trial") {
    if (state.break) {
      const [done, planned] = state.progress;
      await pause(`Take a break. ${done} of ${planned} done.\n\nPress space to continue.`);
    }
    state = await trial(state);
  }
  clear();
  phase(state.phase);
  say("Thank you. The session is over.");
}

run();
