// The lab's page: every robot, whether it is alive and held, and the TA's stop, hold and release.
//
//   GET  /lab.json  every robot: {name, in_folder, alive, held, since, reason, owner_may_release, last}
//   POST /stop      {action: "stop" | "hold" | "release", robots: [] (every robot) or names,
//                    reason, owner_may_release} -> {answers: [{robot, confirmed, held, ms, line}], summary}
// The browser sends the TA's login (HTTP Basic), which it asked for when the page opened.
"use strict";

const $ = (id) => document.getElementById(id);

function link(up, text) {
  $("link").textContent = text;
  $("link").className = up ? "up" : "down";
}

async function send(action, robots) {
  $("summary").textContent = `${action}: asking ${robots.length ? robots.join(", ") : "every robot"}…`;
  try {
    const response = await fetch("/stop", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ action, robots, reason: $("reason").value,
                             owner_may_release: $("owners-release").checked }),
    });
    const answer = await response.json();
    if (!response.ok) throw new Error(`${response.status}: ${answer.message}`);
    $("summary").textContent = answer.summary;
    $("summary").className = answer.answers.every((a) => a.confirmed) ? "ok" : "bad";
  } catch (error) {
    $("summary").textContent = `not sent: ${error.message}`;
    $("summary").className = "bad";
  }
  refresh();
}

function cell(row, text, className = "") {
  const td = row.insertCell();
  td.textContent = text;
  if (className) td.className = className;
  return td;
}

function show(robots) {
  const body = $("robots").tBodies[0];
  body.replaceChildren();
  for (const robot of robots) {
    const row = body.insertRow();
    row.dataset.robot = robot.name;
    cell(row, robot.name + (robot.in_folder ? "" : " (not in the lab's folder)"));
    cell(row, robot.alive ? "alive" : "not seen", robot.alive ? "ok" : "bad");
    const held = robot.held
      ? `held since ${new Date(robot.since / 1e6).toLocaleTimeString()}${robot.reason ? ": " + robot.reason : ""}` +
        (robot.owner_may_release ? " (its owner may release)" : "")
      : "no";
    cell(row, held, robot.held ? "held" : "");
    const last = robot.last;
    cell(row, last ? last.line : "–", last ? (last.confirmed ? "ok" : "bad") : "");
    const buttons = cell(row, "");
    for (const action of ["stop", "hold", "release"]) {
      const button = document.createElement("button");
      button.textContent = action;
      button.className = action;
      button.addEventListener("click", () => send(action, [robot.name]));
      buttons.append(button);
    }
  }
}

async function refresh() {
  try {
    const response = await fetch("/lab.json", { cache: "no-store" });
    if (!response.ok) throw new Error(`${response.status}`);
    const lab = await response.json();
    show(lab.robots);
    link(true, `${lab.robots.filter((r) => r.alive).length} of ${lab.robots.length} robots alive`);
  } catch (error) {
    link(false, `no answer from the lab machine (${error.message})`);
  }
}

$("stop-all").addEventListener("click", () => send("stop", []));
$("hold-all").addEventListener("click", () => send("hold", []));
$("release-all").addEventListener("click", () => send("release", []));
refresh();
setInterval(refresh, 1000);
