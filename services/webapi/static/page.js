// The robot's page: battery, poses, camera and markers, services, log, and a drive pad.
//
// Everything goes through the web API's HTTP bridge to the bus (docs/webapi.md), exactly as a
// page of your own could:
//   GET /bus/icefloe/<robot>/**?_rate=10  (Accept: text/event-stream): every key of the robot, at
//                                          most 10 samples a second each, and its services' tokens
//   GET /bus/log                          (event stream): every log line, in order
//   (judge/state among them: the lap judge's lap in progress, shown when a judge runs)
//   PUT /bus/cmd/twist, PUT /bus/cmd/stop: drive and stop
//   PUT /bus/cmd/car                      : drive as the robot's virtual car ("as a car"); its
//                                          state, car/state, comes with the robot's keys above
// While the lab's TA holds the robot stopped (hw/hold), the page says so and does not drive.
// Each event is {"key", "value", "encoding", "time"}; value is the message (schemas/json/).
"use strict";

const $ = (id) => document.getElementById(id);
let robot = null; // /page/robot.json: name, deadman_s, max_wheel_speed, track, camera size, car

function nameOf(key) {
  // "icefloe/sim/odom/pose" -> "odom/pose"
  return key.split("/").slice(2).join("/");
}

// ---------------------------------------------------------------- reading the bus

function follow(path, onSample) {
  // A Server-Sent Events stream of the bridge; the browser reconnects by itself.
  const source = new EventSource(path);
  source.addEventListener("PUT", (event) => onSample(JSON.parse(event.data), "PUT"));
  source.addEventListener("DELETE", (event) => onSample(JSON.parse(event.data), "DELETE"));
  source.addEventListener("open", () => link(true));
  source.addEventListener("error", () => {
    link(false);
    drive.stop("lost the robot"); // do not drive blind
  });
  return source;
}

function link(up) {
  $("link").textContent = up ? "connected" : "no connection";
  $("link").className = up ? "up" : "down";
}

const shown = {
  battery: 0, // when power/battery last came: it has the state, hw/battery only the reading
  trail: { odom: [], loc: [], car: [] },
  landmarks: new Map(), // stamp -> detected markers, to draw on the picture they came from
  lastLandmarks: [],
  services: new Set(),
  held: false, // hw/hold: the lab's TA holds the robot stopped
};

function onSample(sample, kind) {
  const name = nameOf(sample.key);
  const v = sample.value;
  if (name.startsWith("alive/")) return showService(name.slice(6), kind === "PUT");
  switch (name) {
    case "power/battery":
      shown.battery = Date.now();
      showBattery(v.voltage, v.current, v.state);
      break;
    case "hw/battery":
      if (Date.now() - shown.battery > 5000) showBattery(v.voltage, v.current, "");
      break;
    case "odom/pose":
      showPose("odom", v);
      break;
    case "loc/pose":
      showPose("loc", v);
      break;
    case "car/state":
      showCar(v);
      break;
    case "camera/landmarks":
      shown.landmarks.set(v.stamp, v.landmarks);
      shown.lastLandmarks = v.landmarks;
      if (shown.landmarks.size > 50) shown.landmarks.delete(shown.landmarks.keys().next().value);
      $("markers").textContent = v.landmarks.length
        ? v.landmarks.map((l) => `#${l.id}: ${l.range.toFixed(2)} m, ${deg(l.bearing)}°`).join(" · ")
        : "no markers";
      break;
    case "camera/image":
      showImage(v);
      break;
    case "hw/hold":
      showHold(v);
      break;
    case "judge/state":
      showJudge(v);
      break;
  }
}

function showHold(hold) {
  // hwbridge says it at each change and once a second; while held it refuses every motion command.
  shown.held = hold.held;
  $("hold").hidden = !hold.held;
  if (!hold.held) return;
  const who = hold.owner_may_release ? "the lab's TA or its owner" : "the lab's TA";
  $("hold").textContent = `held stopped by the lab's TA${hold.reason ? ": " + hold.reason : ""}`;
  $("hold").title = `since ${new Date(hold.since / 1e6).toLocaleTimeString()}; driving is refused until ${who} releases it`;
  if (drive.timer !== null) drive.stop("held by the lab's TA: stopped");
  drive.show(`held by the lab's TA: driving is refused until ${who} releases it`);
}

function showJudge(state) {
  // The lap judge's lap in progress (judge/state): time, penalties, the latest events.
  $("judge-box").hidden = false;
  $("judge-track").textContent = state.track;
  $("judge-lap").textContent = state.lap ? String(state.lap) : "– (waiting at the start line)";
  $("judge-time").textContent = state.lap_time.toFixed(1);
  $("judge-penalties").textContent = state.penalties.toFixed(0);
  $("judge-tyres").textContent = state.tyre_off;
  $("judge-bogged").textContent = state.bogged;
  $("judge-stops").textContent = state.ran_stop;
  $("judge-best").textContent = state.laps
    ? `${state.laps} laps done, best score ${state.best_score.toFixed(2)} s` : "";
  $("judge-events").replaceChildren(
    ...state.events.map((e) => {
      const item = document.createElement("li");
      item.className = e.penalty > 0 ? "penalty" : "";
      item.textContent = e.penalty > 0 ? `${e.text} (+${e.penalty.toFixed(0)} s)` : e.text;
      return item;
    }),
  );
}

function showCar(state) {
  // hwbridge's virtual car: its steering after the rate limit, and its bicycle model's pose.
  showPose("car", state);
  $("car-steer").textContent = state.steer.toFixed(2);
  $("car-steer-target").textContent = state.steer_target.toFixed(2);
  $("car-v").textContent = state.v.toFixed(2);
  const tan = Math.tan(Math.abs(state.steer));
  $("car-radius").textContent = tan > 1e-6
    ? `a circle of ${(robot.car.wheelbase / tan).toFixed(2)} m to the ${state.steer > 0 ? "left" : "right"}`
    : "straight";
}

function deg(rad) {
  return ((rad * 180) / Math.PI).toFixed(1);
}

function showBattery(voltage, current, state) {
  $("battery-voltage").textContent = voltage.toFixed(2);
  $("battery-current").textContent = current.toFixed(2);
  $("battery-state").textContent = state || "reading from the board";
  $("battery-box").className = state ? `battery-${state}` : "";
}

function showPose(which, pose) {
  $(`${which}-x`).textContent = pose.x.toFixed(3);
  $(`${which}-y`).textContent = pose.y.toFixed(3);
  $(`${which}-theta`).textContent = deg(pose.theta);
  const trail = shown.trail[which];
  const last = trail[trail.length - 1];
  if (!last || Math.hypot(pose.x - last.x, pose.y - last.y) > 0.005 || pose.theta !== last.theta) {
    trail.push({ x: pose.x, y: pose.y, theta: pose.theta });
    if (trail.length > 600) trail.shift();
    drawMap();
  }
}

function drawMap() {
  // The tracks of both poses, the robot as a triangle; the view grows to fit (at least ±1 m).
  const canvas = $("map");
  const g = canvas.getContext("2d");
  const points = [...shown.trail.odom, ...shown.trail.loc, ...shown.trail.car];
  const reach = Math.max(1, ...points.map((p) => Math.max(Math.abs(p.x), Math.abs(p.y)) * 1.1));
  const scale = Math.min(canvas.width, canvas.height) / (2 * reach);
  const at = (p) => [canvas.width / 2 + p.x * scale, canvas.height / 2 - p.y * scale];
  g.clearRect(0, 0, canvas.width, canvas.height);
  g.strokeStyle = "#c5ced8";
  g.beginPath();
  g.moveTo(0, canvas.height / 2);
  g.lineTo(canvas.width, canvas.height / 2);
  g.moveTo(canvas.width / 2, 0);
  g.lineTo(canvas.width / 2, canvas.height);
  g.stroke();
  for (const [which, colour] of [["odom", "#1f6fb5"], ["loc", "#d9730d"], ["car", "#2e8b57"]]) {
    const trail = shown.trail[which];
    if (!trail.length) continue;
    g.strokeStyle = colour;
    g.beginPath();
    trail.forEach((p, i) => (i ? g.lineTo(...at(p)) : g.moveTo(...at(p))));
    g.stroke();
    const p = trail[trail.length - 1];
    const [x, y] = at(p);
    g.fillStyle = colour;
    g.beginPath();
    g.moveTo(x + 10 * Math.cos(p.theta), y - 10 * Math.sin(p.theta));
    g.lineTo(x + 6 * Math.cos(p.theta + 2.5), y - 6 * Math.sin(p.theta + 2.5));
    g.lineTo(x + 6 * Math.cos(p.theta - 2.5), y - 6 * Math.sin(p.theta - 2.5));
    g.fill();
  }
}

function showImage(image) {
  // image.data is the JPEG, base64 (bytes travel as base64 in JSON); markers are drawn on top,
  // those detected in this very frame when we have them (same stamp), else the latest.
  const picture = new Image();
  picture.onload = () => {
    const canvas = $("camera");
    canvas.width = image.width;
    canvas.height = image.height;
    const g = canvas.getContext("2d");
    g.drawImage(picture, 0, 0);
    const markers = shown.landmarks.get(image.stamp) || shown.lastLandmarks;
    const scale = image.width / robot.camera.width; // corners are in the capture's pixels
    g.strokeStyle = "#00e060";
    g.fillStyle = "#00e060";
    g.lineWidth = 2;
    g.font = "14px sans-serif";
    for (const marker of markers) {
      const c = marker.corners.map((value) => value * scale);
      if (c.length < 8) continue;
      g.beginPath();
      g.moveTo(c[0], c[1]);
      for (let i = 2; i < 8; i += 2) g.lineTo(c[i], c[i + 1]);
      g.closePath();
      g.stroke();
      g.fillText(`#${marker.id}`, c[0], c[1] - 4);
    }
  };
  picture.src = `data:image/jpeg;base64,${image.data}`;
}

function showService(name, alive) {
  if (alive) shown.services.add(name);
  else shown.services.delete(name);
  const list = $("services");
  list.replaceChildren(
    ...[...shown.services].sort().map((s) => {
      const item = document.createElement("li");
      item.textContent = s;
      return item;
    }),
  );
}

function onLog(sample) {
  const line = sample.value;
  const item = document.createElement("li");
  item.className = line.level;
  item.textContent = `${line.service}: ${line.text}`;
  const log = $("log");
  log.append(item);
  while (log.children.length > 50) log.firstChild.remove();
  log.scrollTop = log.scrollHeight;
}

// ---------------------------------------------------------------- driving

async function put(name, message) {
  // keepalive: the request is sent even while the page is being closed (the last stop).
  const response = await fetch(`/bus/${name}`, {
    method: "PUT",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(message),
    keepalive: true,
  });
  if (!response.ok) {
    const why = await response.json().catch(() => ({ message: response.statusText }));
    throw new Error(`${response.status}: ${why.message}`);
  }
}

const drive = {
  // The robot's deadman stops the wheels when no command came for deadman_s (0.5 s): while a
  // button or key is held, the page sends the twist every 100 ms, its heartbeat. When the page
  // is hidden, closed, frozen or cut off, the heartbeat stops, and so does the robot; we also
  // send a stop at once whenever we can. As a car (carMode), the same pad sends cmd/car: ▲ ▼ the
  // speed, ◀ ▶ the steering angle of the steering slider, left positive.
  held: new Map(), // what is held (a button or a key) -> [v, w] direction (w: the steering, as a car)
  carMode: false,
  timer: null,
  inFlight: 0,

  press(what, direction) {
    if (shown.held) return this.show("held by the lab's TA: driving is refused until it is released");
    this.held.set(what, direction);
    if (this.timer === null) {
      this.timer = setInterval(() => this.beat(), 100);
      this.beat();
    }
  },

  release(what) {
    this.held.delete(what);
    if (this.held.size === 0 && this.timer !== null) this.stop("stopped");
  },

  beat() {
    let v = 0;
    let w = 0;
    for (const [dv, dw] of this.held.values()) {
      v += dv;
      w += dw;
    }
    const speed = Number($("speed").value);
    v = Math.max(-1, Math.min(1, v));
    w = Math.max(-1, Math.min(1, w));
    const [key, command, says] = this.carMode
      ? ["cmd/car", { v: v * speed, steer: w * Number($("steer").value) },
         (c) => `driving as a car: v ${c.v.toFixed(2)} m/s, steer ${c.steer.toFixed(2)} rad`]
      : ["cmd/twist", { v: v * speed, w: (w * 2 * speed) / robot.track }, // turn with the wheels at ±speed
         (c) => `driving: v ${c.v.toFixed(2)} m/s, w ${c.w.toFixed(2)} rad/s`];
    if (this.inFlight >= 2) return; // the bridge is slow: never pile up old commands
    this.inFlight += 1;
    put(key, command)
      // A command answered after the stop must not say "driving" over "stopped".
      .then(() => this.timer !== null && this.show(says(command)))
      .catch((error) => this.timer !== null && this.show(`not driving: ${error.message}`))
      .finally(() => (this.inFlight -= 1));
  },

  stop(why) {
    const moving = this.timer !== null;
    clearInterval(this.timer);
    this.timer = null;
    this.held.clear();
    document.querySelectorAll("#pad button.held").forEach((b) => b.classList.remove("held"));
    if (!moving && why !== "stopped") return;
    this.show(why);
    put("cmd/stop", {}).catch((error) => this.show(`stop not sent (${error.message}): the deadman stops it`));
  },

  show(text) {
    $("drive-state").textContent = text;
  },
};

const KEYS = { ArrowUp: [1, 0], ArrowDown: [-1, 0], ArrowLeft: [0, 1], ArrowRight: [0, -1] };

function setUpDrivePad() {
  for (const button of document.querySelectorAll("#pad button[data-v]")) {
    const direction = [Number(button.dataset.v), Number(button.dataset.w)];
    button.addEventListener("pointerdown", (event) => {
      button.setPointerCapture(event.pointerId);
      button.classList.add("held");
      drive.press(button, direction);
    });
    for (const end of ["pointerup", "pointercancel", "lostpointercapture"]) {
      button.addEventListener(end, () => {
        button.classList.remove("held");
        drive.release(button);
      });
    }
  }
  $("stop").addEventListener("click", () => drive.stop("stopped"));
  document.addEventListener("keydown", (event) => {
    if (event.key === " ") drive.stop("stopped");
    if (!(event.key in KEYS) || event.repeat) return;
    event.preventDefault();
    drive.press(event.key, KEYS[event.key]);
  });
  document.addEventListener("keyup", (event) => {
    if (event.key in KEYS) drive.release(event.key);
  });
  // The page is hidden (another tab, minimised), loses focus, or is being closed: stop now.
  document.addEventListener("visibilitychange", () => document.hidden && drive.stop("page hidden: stopped"));
  window.addEventListener("blur", () => drive.stop("page lost focus: stopped"));
  window.addEventListener("pagehide", () => drive.stop("page closed: stopped"));
  $("speed").addEventListener("input", () => ($("speed-value").textContent = $("speed").value));
  $("steer").addEventListener("input", () => ($("steer-value").textContent = Number($("steer").value).toFixed(2)));
  $("car-mode").addEventListener("change", () => setCarMode($("car-mode").checked));
}

function setCarMode(on) {
  // Switching stops the robot: what was held was meant for the other mode.
  if (drive.timer !== null) drive.stop(on ? "stopped: now driving as a car" : "stopped: now driving as a unicycle");
  else drive.show(on ? "stopped (as a car: ▲ ▼ drive, ◀ ▶ steer)" : "stopped");
  drive.carMode = on;
  $("steer-box").hidden = !on;
  $("car-state").hidden = !on;
  const titles = on
    ? { 1: "steer left (←)", "-1": "steer right (→)" }
    : { 1: "turn left (←)", "-1": "turn right (→)" };
  for (const button of document.querySelectorAll("#pad button[data-v='0']")) button.title = titles[button.dataset.w];
}

async function main() {
  robot = await (await fetch("/page/robot.json")).json();
  document.title = `${robot.robot} · icefloe`;
  $("robot").textContent = robot.robot;
  $("speed").max = robot.max_wheel_speed;
  $("steer").max = robot.car.max_steer; // in twelfths of it: full lock, half (the start), ...
  $("steer").min = $("steer").step = robot.car.max_steer / 12;
  $("steer").value = robot.car.max_steer / 2;
  $("steer-value").textContent = Number($("steer").value).toFixed(2);
  setCarMode($("car-mode").checked); // a reload keeps the box ticked
  setUpDrivePad();
  follow(`/bus/icefloe/${robot.robot}/**?_rate=10`, onSample);
  follow("/bus/log", onLog);
}

main();
