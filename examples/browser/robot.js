// The robot's bus from JavaScript, through the web API's HTTP bridge (docs/webapi.md):
//   GET /bus/<key> with Accept: text/event-stream  follow a key (EventSource)
//   PUT /bus/<key> with a JSON body                 publish (checked against the key's message)
// A robot with access control lets anyone follow it; publishing needs its owner's user and
// password (HTTP Basic), as over Zenoh.
"use strict";

let robot = null;         // "http://<robot>:8080"
let login = {};           // {Authorization: "Basic ..."} once a user is given
const streams = [];
const $ = (id) => document.getElementById(id);

// Follow a key: every sample's message, at most `rate` a second (the bridge drops older ones).
function follow(key, rate, onMessage) {
  const source = new EventSource(`${robot}/bus/${key}?_rate=${rate}`);
  source.addEventListener("PUT", (event) => onMessage(JSON.parse(event.data).value));
  source.onerror = () => { $("state").textContent = "no answer from the robot"; };
  streams.push(source);
}

// Publish a message; the bridge answers 400 naming the field of a bad one, 401/403 if not allowed.
async function put(key, message) {
  const response = await fetch(`${robot}/bus/${key}`, {
    method: "PUT",
    headers: {"Content-Type": "application/json", ...login},
    body: JSON.stringify(message),
  });
  if (!response.ok) {
    $("state").textContent = `${key}: ${response.status} ${(await response.json()).message}`;
  }
  return response.ok;
}

// Drive while a button is held: repeat the twist (the robot stops when commands stop coming).
let timer = null;
function drive(v, w) {
  halt();
  const send = () => put("cmd/twist", {v, w});
  send();
  timer = setInterval(send, 100);
  $("state").textContent = "driving";
}
function halt() {
  if (timer === null) return;
  clearInterval(timer);
  timer = null;
  put("cmd/stop", {});
  $("state").textContent = "stopped";
}

$("connect").addEventListener("submit", (event) => {
  event.preventDefault();
  halt();
  streams.splice(0).forEach((s) => s.close());
  robot = $("address").value.replace(/\/$/, "");
  const user = $("user").value;
  login = user ? {Authorization: "Basic " + btoa(`${user}:${$("password").value}`)} : {};
  follow("hw/battery", 2, (b) => { $("battery").textContent = b.voltage.toFixed(2); });
  follow("odom/pose", 10, (p) => { $("x").textContent = p.x.toFixed(3); $("y").textContent = p.y.toFixed(3); });
  $("state").textContent = "connected";
});

for (const button of document.querySelectorAll("button[data-v]")) {
  button.addEventListener("pointerdown", () => drive(Number(button.dataset.v), Number(button.dataset.w)));
  for (const end of ["pointerup", "pointerleave", "pointercancel"]) button.addEventListener(end, halt);
}
document.addEventListener("visibilitychange", () => { if (document.hidden) halt(); });

// ?robot=http://host:port connects at once (as the test suite opens it).
const given = new URLSearchParams(location.search).get("robot");
if (given) {
  $("address").value = given;
  $("connect").requestSubmit();
}
