// The live-sparring viewer: draws both fighters as MuJoCo sees them (the welcome's collision
// geoms) and steers the partner with the keyboard, in the protocol's "commands" mode
// (docs/spar-protocol.md). `window.spar` exposes what the browser test checks.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const TURN_STEP = Math.PI / 2; // rad per press of a left/right arrow; held keys do not repeat
const SPEED_STEP = 0.25; // m/s per press of an up/down arrow
const MAX_SPEED = 2; // the protocol's bound
const RESEND_MS = 250; // the server keeps the latest command; resending is a heartbeat
const MAX_ERRORS = 5;

const spar = {
  states: 0, // received
  last: null, // the last state message
  welcome: null,
  heading: null, // commanded, rad
  speed: 0, // commanded, m/s
  seq: 0, // of the last command sent
  totals: {}, // role -> damage summed over the states received, N
  errors: [],
};
window.spar = spar;

const $ = (id) => document.getElementById(id);
const wrap = (angle) => Math.atan2(Math.sin(angle), Math.cos(angle));

function showError(text) {
  spar.errors.push(text);
  const item = document.createElement('li');
  item.textContent = text;
  $('errors').append(item);
  while ($('errors').children.length > MAX_ERRORS) $('errors').firstChild.remove();
}

function setStatus(text, kind) {
  $('status').textContent = text;
  $('status').className = kind;
}

// --- the scene ---------------------------------------------------------------------------

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20242a);
const camera = new THREE.PerspectiveCamera(45, innerWidth / innerHeight, 0.05, 100);
camera.position.set(0, 1.6, 4);
let renderer = null;
let controls = null;
try {
  renderer = new THREE.WebGLRenderer({ antialias: true });
  renderer.setPixelRatio(devicePixelRatio);
  renderer.setSize(innerWidth, innerHeight);
  $('scene').append(renderer.domElement);
  controls = new OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 1, 0);
} catch (error) {
  // Without WebGL the numbers and the steering still work; say why nothing is drawn.
  showError(`cannot draw the scene (WebGL): ${error.message}`);
}

scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 2.0));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(2, 6, 4);
scene.add(sun);

// MuJoCo's world is z-up, three.js's y-up: everything from the server goes in this group.
const world = new THREE.Group();
world.rotation.x = -Math.PI / 2;
scene.add(world);

const floor = new THREE.Mesh(
  new THREE.PlaneGeometry(20, 20),
  // Pushed back in depth, or the grid's lines flicker in and out of it at grazing angles.
  new THREE.MeshStandardMaterial({
    color: 0x3b4048,
    roughness: 1,
    polygonOffset: true,
    polygonOffsetFactor: 1,
    polygonOffsetUnits: 1,
  }),
);
world.add(floor);
// A ring's size in 0.5 m squares. (Software WebGL loses grid lines that pass behind the
// camera, which a floor-sized grid's do.)
const grid = new THREE.GridHelper(8, 16, 0x8a93a0, 0x555d68);
grid.rotation.x = Math.PI / 2; // GridHelper lies in its y-up xz plane; the floor is z = 0
world.add(grid);

const fighters = new THREE.Group();
world.add(fighters);
let bodiesOf = {}; // role -> one Group per body, in the welcome's `bodies` order

function geometry(geom) {
  const [a, b, c] = geom.size;
  if (geom.shape === 'sphere') return new THREE.SphereGeometry(a, 24, 16);
  if (geom.shape === 'box') return new THREE.BoxGeometry(2 * a, 2 * b, 2 * c);
  if (geom.shape === 'capsule') {
    // three.js builds capsules along y, MuJoCo along the geom's z.
    return new THREE.CapsuleGeometry(a, 2 * b, 8, 16).rotateX(Math.PI / 2);
  }
  return null;
}

function buildFighters(welcome) {
  fighters.clear();
  bodiesOf = {};
  for (const fighter of welcome.fighters) {
    const bodies = welcome.bodies.map(() => new THREE.Group());
    for (const geom of fighter.geoms) {
      const shape = geometry(geom);
      if (shape === null) {
        showError(`${fighter.role}: cannot draw a ${geom.shape}`);
        continue;
      }
      const [r, g, b, alpha] = geom.rgba;
      const material = new THREE.MeshStandardMaterial({ roughness: 0.7 });
      material.color.setRGB(r, g, b, THREE.SRGBColorSpace); // MuJoCo's colours are as seen
      if (alpha < 1) Object.assign(material, { transparent: true, opacity: alpha });
      const mesh = new THREE.Mesh(shape, material);
      mesh.position.fromArray(geom.pos);
      const [w, x, y, z] = geom.quat;
      mesh.quaternion.set(x, y, z, w);
      bodies[geom.body].add(mesh);
    }
    bodies.forEach((body) => fighters.add(body));
    bodiesOf[fighter.role] = bodies;
  }
}

// The camera follows the fighters' midpoint, so orbiting stays around the action.
let followed = null;

function follow(state) {
  const pelvises = state.fighters.map((f) => f.bodies[spar.welcome.bodies[0]]);
  const [x, y, z] = [0, 1, 2].map((i) => (pelvises[0][i] + pelvises[1][i]) / 2);
  // The world group's rotation, by hand; aimed a little above the pelvises, so that the
  // fighters stand clear of the numbers in the top left corner.
  const middle = new THREE.Vector3(x, z + 0.3, -y);
  if (followed === null) {
    camera.position.copy(middle).add(new THREE.Vector3(1.6, 1.4, 4.6)); // from the side, above
  } else {
    camera.position.add(middle.clone().sub(followed));
  }
  if (controls) controls.target.copy(middle);
  followed = middle;
}

function place(state) {
  for (const fighter of state.fighters) {
    const bodies = bodiesOf[fighter.role];
    if (!bodies) continue;
    spar.welcome.bodies.forEach((name, i) => {
      const [x, y, z, qw, qx, qy, qz] = fighter.bodies[name];
      bodies[i].position.set(x, y, z);
      bodies[i].quaternion.set(qx, qy, qz, qw);
    });
  }
  follow(state);
}

// Draw only when something changed (a state, the camera): software WebGL (a browser without
// a GPU) takes tens of milliseconds a frame, which would delay the states and the keys.
let dirty = true;
const redraw = () => (dirty = true);

function resize() {
  camera.aspect = innerWidth / innerHeight;
  camera.updateProjectionMatrix();
  if (renderer) renderer.setSize(innerWidth, innerHeight);
  redraw();
}
addEventListener('resize', resize);
if (renderer) {
  controls.addEventListener('change', redraw);
  renderer.setAnimationLoop(() => {
    controls.update();
    if (!dirty) return;
    dirty = false;
    renderer.render(scene, camera);
  });
}

// --- the numbers -------------------------------------------------------------------------

let late = 0;

function flash(row, name) {
  row.classList.remove(name);
  void row.offsetWidth; // restarts the animation when the class comes back at once
  row.classList.add(name);
}

function showState(state) {
  for (const fighter of state.fighters) {
    const row = $(`fighter-${fighter.role}`);
    if (!row) continue;
    const total = (spar.totals[fighter.role] ?? 0) + fighter.damage_n;
    spar.totals[fighter.role] = total;
    row.querySelector('.damage').textContent = fighter.damage_n.toFixed(0);
    row.querySelector('.total').textContent = total.toFixed(0);
    row.querySelector('.falls').textContent = fighter.falls;
    if (fighter.damage_n > 0) flash(row, 'hit');
    if (fighter.fell) flash(row, 'fell');
  }
  if (state.late) late += 1;
  $('clock').textContent =
    `step ${state.step}, t ${state.t.toFixed(1)} s, server step ${state.step_ms.toFixed(1)} ms, ` +
    `late states ${late}${state.reset ? ', bout restarted' : ''}`;
}

function showCommand() {
  const degrees = spar.heading === null ? '-' : `${((spar.heading * 180) / Math.PI).toFixed(0)}°`;
  $('heading').textContent = degrees;
  $('speed').textContent = spar.speed.toFixed(2);
}

// --- the connection ----------------------------------------------------------------------

const token = new URLSearchParams(location.search).get('token');
const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
const socket = new WebSocket(`${scheme}://${location.host}/spar`);

function sendCommand() {
  // No command before the first state: the heading starts as the partner's own, so the
  // partner does not spin round on connecting.
  if (socket.readyState !== WebSocket.OPEN || spar.heading === null) return;
  spar.seq += 1;
  socket.send(
    JSON.stringify({ type: 'command', seq: spar.seq, heading: spar.heading, speed: spar.speed }),
  );
}

socket.addEventListener('open', () => {
  setStatus('open, waiting for the welcome', 'open');
  const hello = { type: 'hello', protocol: 1, mode: 'commands' };
  if (token !== null) hello.token = token;
  socket.send(JSON.stringify(hello));
});

socket.addEventListener('message', (event) => {
  let message;
  try {
    message = JSON.parse(event.data);
  } catch {
    showError(`the server sent a frame that is not JSON: ${String(event.data).slice(0, 80)}`);
    return;
  }
  if (message.type === 'welcome') {
    spar.welcome = message;
    buildFighters(message);
    setStatus(`connected, session ${message.session}`, 'open');
  } else if (message.type === 'state') {
    if (spar.welcome === null) return;
    spar.states += 1;
    spar.last = message;
    if (spar.heading === null) {
      spar.heading = message.fighters.find((f) => f.role === 'partner').heading;
      showCommand();
    }
    place(message);
    showState(message);
    redraw();
  } else if (message.type === 'error') {
    showError(`${message.code}: ${message.message}`);
  } else {
    showError(`unknown message type ${message.type}`);
  }
});

socket.addEventListener('close', (event) => {
  const why = event.reason ? `, ${event.reason}` : '';
  setStatus(`closed (${event.code}${why}); reload the page to reconnect`, 'closed');
});

setInterval(sendCommand, RESEND_MS);

// --- the keyboard ------------------------------------------------------------------------

addEventListener('keydown', (event) => {
  if (event.ctrlKey || event.metaKey || event.altKey) return; // the browser's (Ctrl+S saves)
  const speed = (v) => Math.min(MAX_SPEED, Math.max(0, v));
  if (event.key === 'ArrowLeft' || event.key === 'ArrowRight') {
    event.preventDefault();
    if (event.repeat || spar.heading === null) return;
    const turn = event.key === 'ArrowLeft' ? TURN_STEP : -TURN_STEP; // yaw is counter-clockwise
    spar.heading = wrap(spar.heading + turn);
  } else if (event.key === 'ArrowUp' || event.key === 'ArrowDown') {
    event.preventDefault();
    spar.speed = speed(spar.speed + (event.key === 'ArrowUp' ? SPEED_STEP : -SPEED_STEP));
  } else if (event.key === 's' || event.key === 'S') {
    spar.speed = 0;
  } else {
    return;
  }
  showCommand();
  sendCommand();
});
