// stitch's live viewer: the merged map's points, each submap's keyframe trajectory, the camera,
// the submap graph and the flight's state, pushed by stitch-viewer over a WebSocket (/live).
// The page reads nothing but its own server. State for tests is mirrored on <body data-*>.
'use strict';

(function () {
  const body = document.body;
  const errors = [];
  function noteError(text) {
    errors.push(text);
    body.dataset.errors = String(errors.length);
    const box = document.getElementById('errors');
    box.hidden = false;
    box.textContent = errors.join('\n');
  }
  window.addEventListener('error', (e) => noteError(String(e.message)));
  window.addEventListener('unhandledrejection', (e) => noteError('unhandled: ' + String(e.reason)));
  const consoleError = console.error.bind(console);
  console.error = (...args) => {
    noteError(args.map(String).join(' '));
    consoleError(...args);
  };

  // --- The 3D view ---------------------------------------------------------------------------
  const canvas = document.getElementById('view');
  const renderer = new THREE.WebGLRenderer({ canvas: canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  const background = new THREE.Color(0x10141a);
  const scene = new THREE.Scene();
  scene.background = background;
  const camera = new THREE.PerspectiveCamera(55, 1, 0.01, 1e6);
  camera.position.set(0, -30, -30);
  const controls = new THREE.OrbitControls(camera, canvas);
  controls.enableDamping = true;
  controls.screenSpacePanning = true;

  const pointsMaterial = new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: THREE.VertexColors });
  let points = null;        // THREE.Points of the cloud
  let cloud = null;         // { positions: Float32Array, colours: Uint8Array, components: Uint8Array }
  const trajectories = new THREE.Group();
  scene.add(trajectories);
  const frustum = new THREE.LineSegments(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: 0xffffff }));
  frustum.visible = false;
  scene.add(frustum);

  let map = null;           // the last map update
  let earth = null;         // where the fixes place the largest merged map (map.on_earth), or null
  let live = null;          // the last live update
  let offsets = {};         // merged map (component) -> THREE.Vector3 that sets it apart
  let up = new THREE.Vector3(0, -1, 0);  // the map's up (the normal of the plane of motion)
  let follow = false;
  // The view frames the map until it has framed its points (the path alone may come first, and a
  // handheld camera's path is a fraction of its scene), or until the user moves it.
  let needsFit = true;
  controls.addEventListener('start', () => { needsFit = false; });

  function resize() {
    const width = canvas.clientWidth, height = canvas.clientHeight;
    if (canvas.width !== Math.floor(width * renderer.getPixelRatio()) ||
        canvas.height !== Math.floor(height * renderer.getPixelRatio())) {
      renderer.setSize(width, height, false);
      camera.aspect = width / Math.max(1, height);
      camera.updateProjectionMatrix();
    }
  }

  // Everything drawn, component by component: cloud points and keyframe positions.
  function eachPosition(visit) {
    if (cloud) {
      const p = cloud.positions;
      for (let i = 0; i < cloud.components.length; ++i) visit(cloud.components[i], p[3 * i], p[3 * i + 1], p[3 * i + 2]);
    }
    if (map) {
      for (const s of map.submaps) for (const q of s.trajectory) visit(s.component, q[0], q[1], q[2]);
    }
  }

  // The plane of the motion: the smallest principal axis of the keyframe positions is up
  // (a survey flies over a plane; a handheld camera walks on one).
  function estimateUp() {
    if (earth) {  // placed on Earth: up is up
      up = new THREE.Vector3(earth.up[0], earth.up[1], earth.up[2]).normalize();
      camera.up.copy(up);
      return;
    }
    const samples = [];
    if (map) for (const s of map.submaps) if (s.component === 0) for (const q of s.trajectory) samples.push(q);
    if (samples.length < 3) return;
    const mean = [0, 0, 0];
    for (const q of samples) for (let k = 0; k < 3; ++k) mean[k] += q[k] / samples.length;
    const c = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
    for (const q of samples) {
      for (let i = 0; i < 3; ++i) for (let j = 0; j < 3; ++j) c[i][j] += (q[i] - mean[i]) * (q[j] - mean[j]);
    }
    // Jacobi rotations: eigenvectors of the 3x3 covariance.
    const v = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    for (let sweep = 0; sweep < 20; ++sweep) {
      for (const [p, q] of [[0, 1], [0, 2], [1, 2]]) {
        if (Math.abs(c[p][q]) < 1e-12) continue;
        const theta = (c[q][q] - c[p][p]) / (2 * c[p][q]);
        const t = Math.sign(theta || 1) / (Math.abs(theta) + Math.sqrt(theta * theta + 1));
        const cs = 1 / Math.sqrt(t * t + 1), sn = t * cs;
        for (let k = 0; k < 3; ++k) {
          const a = c[k][p], b = c[k][q];
          c[k][p] = cs * a - sn * b; c[k][q] = sn * a + cs * b;
        }
        for (let k = 0; k < 3; ++k) {
          const a = c[p][k], b = c[q][k];
          c[p][k] = cs * a - sn * b; c[q][k] = sn * a + cs * b;
        }
        for (let k = 0; k < 3; ++k) {
          const a = v[k][p], b = v[k][q];
          v[k][p] = cs * a - sn * b; v[k][q] = sn * a + cs * b;
        }
      }
    }
    let smallest = 0;
    for (let k = 1; k < 3; ++k) if (c[k][k] < c[smallest][smallest]) smallest = k;
    const normal = new THREE.Vector3(v[0][smallest], v[1][smallest], v[2][smallest]).normalize();
    // Cameras look down at the ground (+z of a camera): up is against the mean viewing direction,
    // and the map's frame has y down in the first camera: choose the sign that points up there.
    if (normal.y > 0) normal.negate();
    up = normal;
    camera.up.copy(up);
  }

  // Merged maps other than the largest are set apart beside it, in a row.
  function layoutComponents() {
    const boxes = {};
    eachPosition((component, x, y, z) => {
      const b = boxes[component] || (boxes[component] = new THREE.Box3());
      b.expandByPoint(new THREE.Vector3(x, y, z));
    });
    offsets = {};
    const side = new THREE.Vector3(1, 0, 0).projectOnPlane(up).normalize();
    let edge = null;
    for (const key of Object.keys(boxes).map(Number).sort((a, b) => a - b)) {
      const box = boxes[key];
      if (edge === null) {
        offsets[key] = new THREE.Vector3();
        edge = box.max.dot(side);
        continue;
      }
      const size = box.getSize(new THREE.Vector3()).length();
      const shift = edge + 0.25 * size + 1 - box.min.dot(side);
      offsets[key] = side.clone().multiplyScalar(shift);
      edge += 0.25 * size + 1 + (box.max.dot(side) - box.min.dot(side));
    }
  }

  function offsetOf(component) {
    return offsets[component] || new THREE.Vector3();
  }

  function rebuildPoints() {
    if (points) {
      scene.remove(points);
      points.geometry.dispose();
      points = null;
    }
    if (!cloud || cloud.components.length === 0) return;
    const n = cloud.components.length;
    const positions = new Float32Array(3 * n);
    const colours = new Float32Array(3 * n);
    for (let i = 0; i < n; ++i) {
      const o = offsetOf(cloud.components[i]);
      positions[3 * i] = cloud.positions[3 * i] + o.x;
      positions[3 * i + 1] = cloud.positions[3 * i + 1] + o.y;
      positions[3 * i + 2] = cloud.positions[3 * i + 2] + o.z;
      for (let k = 0; k < 3; ++k) colours[3 * i + k] = cloud.colours[3 * i + k] / 255;
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
    geometry.computeBoundingSphere();
    points = new THREE.Points(geometry, pointsMaterial);
    scene.add(points);
  }

  function rebuildTrajectories() {
    while (trajectories.children.length) {
      const line = trajectories.children.pop();
      line.geometry.dispose();
      line.material.dispose();
    }
    if (!map) return;
    for (const s of map.submaps) {
      if (s.trajectory.length < 2) continue;
      const o = offsetOf(s.component);
      const positions = new Float32Array(3 * s.trajectory.length);
      s.trajectory.forEach((q, i) => {
        positions[3 * i] = q[0] + o.x; positions[3 * i + 1] = q[1] + o.y; positions[3 * i + 2] = q[2] + o.z;
      });
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
      const line = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: new THREE.Color(s.colour) }));
      line.name = s.id;
      trajectories.add(line);
    }
  }

  function sceneScale() {
    const box = new THREE.Box3();
    if (points) box.expandByObject(points);
    box.expandByObject(trajectories);
    return box.isEmpty() ? null : box;
  }

  function fitView(fromAbove) {
    const box = sceneScale();
    if (!box) return;
    const centre = box.getCenter(new THREE.Vector3());
    const radius = Math.max(1, box.getSize(new THREE.Vector3()).length() / 2);
    body.dataset.framedRadius = radius.toPrecision(4);  // what the view frames, for tests
    controls.target.copy(centre);
    const away = fromAbove ? up.clone() : up.clone().multiplyScalar(0.8).add(new THREE.Vector3(1, 0, 0).projectOnPlane(up).normalize().multiplyScalar(-0.6));
    camera.position.copy(centre).add(away.normalize().multiplyScalar(radius * 1.9));
    camera.near = radius / 1000;
    camera.far = radius * 100;
    camera.updateProjectionMatrix();
    controls.update();
  }

  // The camera's frustum at its pose in its merged map (set apart like its map).
  function updateFrustum() {
    frustum.visible = false;
    if (!live) return;
    for (const agent of Object.keys(live.aircraft)) {
      const cam = live.aircraft[agent].camera;
      if (!cam || cam.component === null || cam.component === undefined || !cam.position) continue;
      const box = sceneScale();
      const size = box ? Math.max(0.2, box.getSize(new THREE.Vector3()).length() / 60) : 1;
      const w = size * 0.6, h = size * 0.45, d = size;
      const corners = [[-w, -h, d], [w, -h, d], [w, h, d], [-w, h, d]];
      const v = [];
      for (const c of corners) v.push(0, 0, 0, c[0], c[1], c[2]);
      for (let i = 0; i < 4; ++i) {
        const a = corners[i], b = corners[(i + 1) % 4];
        v.push(a[0], a[1], a[2], b[0], b[1], b[2]);
      }
      frustum.geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(v), 3));
      const q = cam.rotation_wxyz;
      frustum.quaternion.set(q[1], q[2], q[3], q[0]);
      frustum.position.set(cam.position[0], cam.position[1], cam.position[2]).add(offsetOf(cam.component));
      frustum.visible = true;
      if (follow) {
        const shift = frustum.position.clone().sub(controls.target);
        controls.target.add(shift);
        camera.position.add(shift);
      }
      break;  // the first aircraft's camera
    }
  }

  // --- The panels ----------------------------------------------------------------------------
  function cell(row, text, className) {
    const td = document.createElement('td');
    td.textContent = text;
    if (className) td.className = className;
    row.appendChild(td);
    return td;
  }

  function showLive() {
    const box = document.getElementById('aircraft');
    box.textContent = '';
    const agents = Object.keys(live.aircraft);
    if (agents.length === 0) {
      const p = document.createElement('p');
      p.className = 'quiet';
      p.textContent = 'no aircraft heard yet';
      box.appendChild(p);
    }
    let firstState = '';
    for (const agent of agents) {
      const a = live.aircraft[agent];
      const table = document.createElement('table');
      table.className = 'figures';
      const add = (name, value, className) => {
        const row = document.createElement('tr');
        const th = document.createElement('th');
        th.textContent = name;
        row.appendChild(th);
        cell(row, value, className);
        table.appendChild(row);
      };
      add('aircraft', agent);
      if (a.tracking) {
        const t = a.tracking;
        if (!firstState) firstState = t.state;
        add('tracking', t.state + (t.detail ? ' (' + t.detail + ')' : ''), 'state-' + t.state);
        add('frame', String(t.frame));
        add('frame rate', t.seconds_ago > 2 ? '- (no frame for ' + t.seconds_ago.toFixed(0) + ' s)' : t.fps.toFixed(1) + ' fps');
        add('submap', t.submap + ', ' + t.submap_keyframes + ' keyframes' +
            (t.map_keyframes >= 0 ? ' (' + t.map_keyframes + ' in the map shown)' : ' (none in the map shown yet)'));
        add('tracked points', String(t.tracked_points) + ' of ' + t.features + ' features');
        add('submaps closed', String(t.submaps_closed));
        add('mapper', t.mapper_connected ? 'connected' : 'not heard');
      }
      for (const l of a.links || []) {
        add('link bridge', 'sends ' + l.forward + ' to ' + l.peer + (l.authenticated ? ', authenticated' : ', NOT authenticated'));
        add('link rate', (l.send_rate_bytes_per_s / 1000).toFixed(1) + ' kB/s sent' +
            (l.budget_bytes_per_s > 0 ? ' of ' + (l.budget_bytes_per_s / 1000).toFixed(0) : ''));
        add('link backlog', l.backlog_s.toFixed(1) + ' s');
        add('link repairs', l.fragments_repaired + ' repaired, ' + l.messages_given_up + ' given up, ' +
            l.datagrams_refused + ' refused');
        add('peer heard', l.seconds_since_peer < 0 ? 'never' : l.seconds_since_peer.toFixed(1) + ' s ago');
      }
      box.appendChild(table);
    }
    body.dataset.tracking = firstState;
  }

  function showMap() {
    document.getElementById('submap-count').textContent = String(map.submaps.length);
    document.getElementById('merged-count').textContent = String(map.merged_maps);
    document.getElementById('keyframe-count').textContent = String(map.keyframes);
    body.dataset.submaps = String(map.submaps.length);
    body.dataset.keyframes = String(map.keyframes);
    const rows = document.querySelector('#submaps tbody');
    rows.textContent = '';
    for (const s of map.submaps) {
      const row = document.createElement('tr');
      const name = cell(row, s.id);
      const swatch = document.createElement('span');
      swatch.className = 'swatch';
      swatch.style.background = s.colour;
      name.prepend(swatch);
      cell(row, String(s.component) + (s.merged ? '' : ' (alone)'));
      cell(row, String(s.keyframes));
      cell(row, String(s.points));
      cell(row, s.closed ? 'closed' : 'open');
      rows.appendChild(row);
    }
    const edgeRows = document.querySelector('#edges tbody');
    edgeRows.textContent = '';
    for (const e of map.edges) {
      const row = document.createElement('tr');
      cell(row, e.a + ' - ' + e.b);
      cell(row, e.C.toFixed(1));
      cell(row, String(e.frames));
      cell(row, String(e.points));
      const joined = e.gnss_sigma_m > 0 ? 'joined by GNSS (\u00b1' + e.gnss_sigma_m.toFixed(2) + ' m)' : 'merged';
      cell(row, e.tree ? joined : (e.refused ? 'refused: ' + e.refused : 'not used'), e.refused ? 'refused' : '');
      edgeRows.appendChild(row);
    }
    drawGraph();
    const log = document.getElementById('merge-log');
    log.textContent = '';
    for (const line of map.merge_log) {
      const item = document.createElement('li');
      const fields = line.split('\t');
      item.textContent = fields[0] + (fields[1] ? ': current map ' + fields[1] : '') + (fields[2] ? '; unconnected ' + fields[2] : '');
      log.appendChild(item);
    }
    log.scrollTop = log.scrollHeight;
  }

  function svg(name, attributes, parent) {
    const element = document.createElementNS('http://www.w3.org/2000/svg', name);
    for (const key of Object.keys(attributes)) element.setAttribute(key, attributes[key]);
    parent.appendChild(element);
    return element;
  }

  function drawGraph() {
    const graph = document.getElementById('graph');
    graph.textContent = '';
    const at = {};
    const n = map.submaps.length;
    map.submaps.forEach((s, i) => {
      const angle = 2 * Math.PI * i / Math.max(1, n) - Math.PI / 2;
      at[s.id] = [80 * Math.cos(angle), 80 * Math.sin(angle)];
    });
    for (const e of map.edges) {
      if (!at[e.a] || !at[e.b]) continue;
      svg('line', { x1: at[e.a][0], y1: at[e.a][1], x2: at[e.b][0], y2: at[e.b][1],
                    stroke: e.gnss_sigma_m > 0 ? '#4090e0' : e.tree ? '#e05050' : (e.refused ? '#704040' : '#556070'),
                    'stroke-width': e.tree ? 3 : 1, 'stroke-dasharray': e.refused ? '3 2' : '' }, graph);
      const label = svg('text', { x: (at[e.a][0] + at[e.b][0]) / 2, y: (at[e.a][1] + at[e.b][1]) / 2 - 5 }, graph);
      label.textContent = e.gnss_sigma_m > 0 ? 'GNSS' : 'C=' + e.C.toFixed(0);
    }
    for (const s of map.submaps) {
      svg('circle', { cx: at[s.id][0], cy: at[s.id][1], r: 14, fill: s.colour, stroke: s.closed ? 'none' : '#fff' }, graph);
      const label = svg('text', { x: at[s.id][0], y: at[s.id][1] }, graph);
      label.textContent = s.id;
    }
  }

  // --- The 2D mosaic view --------------------------------------------------------------------
  // The merger's live orthomosaic of the largest merged map, or on Earth of every map the fixes
  // place, north (its frame's +y) up: its tiles as the live update lists them (each fetched once
  // per version), each submap's outline and trajectory, and the aircraft. #mosaic in the address
  // opens it.
  const mosaicCanvas = document.getElementById('mosaic');
  const mosaicContext = mosaicCanvas.getContext('2d', { willReadFrequently: true });
  const tiles = new Map();  // "col_row" -> { col, row, version, image, loading }
  let mosaicRevision = -1;
  let showMosaic = window.location.hash === '#mosaic';
  let mosaicDrawPending = false;

  function rotate(q, v) {  // q: [w, x, y, z]
    const [w, x, y, z] = q;
    const tx = 2 * (y * v[2] - z * v[1]), ty = 2 * (z * v[0] - x * v[2]), tz = 2 * (x * v[1] - y * v[0]);
    return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)];
  }

  function compose(a, b) {  // similarities: a after b
    const [w1, x1, y1, z1] = a.rotation_wxyz, [w2, x2, y2, z2] = b.rotation_wxyz;
    const r = rotate(a.rotation_wxyz, b.translation);
    return {
      scale: a.scale * b.scale,
      rotation_wxyz: [w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                      w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
      translation: [0, 1, 2].map((i) => a.scale * r[i] + a.translation[i]),
    };
  }

  function updateMosaicTiles() {
    const m = live && live.mosaic;
    if (!m) return;
    if (m.revision !== mosaicRevision) {
      tiles.clear();
      mosaicRevision = m.revision;
    }
    const listed = new Set();
    for (const [col, row, version] of m.tiles) {
      const key = col + '_' + row;
      listed.add(key);
      let tile = tiles.get(key);
      if (!tile) tiles.set(key, tile = { col: col, row: row, version: 0, image: null, loading: 0 });
      if (tile.version >= version || tile.loading >= version) continue;
      tile.loading = version;
      const image = new Image();
      image.onload = () => {
        if (version > tile.version) {
          tile.version = version;
          tile.image = image;
        }
        requestMosaicDraw();
      };
      image.src = '/mosaic/' + key + '.png?v=' + version;
    }
    for (const key of Array.from(tiles.keys())) if (!listed.has(key)) tiles.delete(key);
    requestMosaicDraw();
  }

  function requestMosaicDraw() {
    if (!showMosaic || mosaicDrawPending) return;
    mosaicDrawPending = true;
    window.requestAnimationFrame(() => {
      mosaicDrawPending = false;
      drawMosaic();
    });
  }

  function drawMosaic() {
    const ratio = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.floor(mosaicCanvas.clientWidth * ratio));
    const height = Math.max(1, Math.floor(mosaicCanvas.clientHeight * ratio));
    if (mosaicCanvas.width !== width || mosaicCanvas.height !== height) {
      mosaicCanvas.width = width;
      mosaicCanvas.height = height;
    }
    const c = mosaicContext;
    c.fillStyle = '#10141a';
    c.fillRect(0, 0, width, height);
    const m = live && live.mosaic;
    let shown = 0;
    if (m) {
      // Mosaic pixels of a position in a merged map's frame: into the mosaic's frame (on Earth,
      // through the map's place there), then its grid. The maps drawn: the mosaic's own, or on
      // Earth every map the fixes place.
      const g = m.ground_from_map;
      const transform = (s, p) => {
        const r = rotate(s.rotation_wxyz, p);
        return [0, 1, 2].map((i) => s.scale * r[i] + s.translation[i]);
      };
      const toPixelOf = new Map();  // component -> function
      if (m.frame === 'earth') {
        for (const e of (map && map.on_earth) || []) {
          if (e.enu_from_world) toPixelOf.set(e.component, (p) => transform(g, transform(e.enu_from_world, p)));
        }
      } else {
        const frame = map && map.submaps.find((s) => s.id === m.frame);
        toPixelOf.set(frame ? frame.component : 0, (p) => transform(g, p));
      }
      const gridOf = (q) => [(q[0] - m.origin[0]) / m.gsd, (m.origin[1] - q[1]) / m.gsd];
      const paths = [];
      if (map) {
        for (const s of map.submaps) {
          const to = toPixelOf.get(s.component);
          if (to && s.trajectory.length) paths.push({ colour: s.colour, points: s.trajectory.map((p) => gridOf(to(p))) });
        }
      }
      const aircraft = [];
      if (live) {
        for (const agent of Object.keys(live.aircraft)) {
          const cam = live.aircraft[agent].camera;
          const to = cam && cam.position && toPixelOf.get(cam.component);
          if (to) aircraft.push(gridOf(to(cam.position)));
        }
      }
      // The view holds every tile, path and the aircraft.
      let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
      const extend = (x, y) => { x0 = Math.min(x0, x); y0 = Math.min(y0, y); x1 = Math.max(x1, x); y1 = Math.max(y1, y); };
      for (const t of tiles.values()) {
        if (!t.image) continue;
        extend(t.col * m.tile_px, t.row * m.tile_px);
        extend((t.col + 1) * m.tile_px, (t.row + 1) * m.tile_px);
      }
      for (const p of paths) for (const q of p.points) extend(q[0], q[1]);
      for (const a of aircraft) extend(a[0], a[1]);
      if (x1 > x0 && y1 > y0) {
        const scale = 0.94 * Math.min(width / (x1 - x0), height / (y1 - y0));
        // The scale bar and north arrow measure the largest map's frame: on Earth, its place there.
        const largest = m.frame === 'earth' && ((map && map.on_earth) || []).find((e) => e.component === 0);
        mosaicFrame = { ground_from_map: largest ? compose(g, largest.enu_from_world) : g, gsd: m.gsd, scale: scale };
        const ox = 0.5 * (width - scale * (x1 - x0)) - scale * x0, oy = 0.5 * (height - scale * (y1 - y0)) - scale * y0;
        c.imageSmoothingEnabled = true;
        for (const t of tiles.values()) {
          if (!t.image) continue;
          c.drawImage(t.image, ox + scale * t.col * m.tile_px, oy + scale * t.row * m.tile_px,
                      scale * m.tile_px + 0.5, scale * m.tile_px + 0.5);
          ++shown;
        }
        c.lineWidth = 2 * ratio;
        for (const p of paths) {
          // The submap's outline: the hull of its path (where its keyframes flew).
          const hull = convexHull(p.points);
          c.strokeStyle = p.colour;
          c.setLineDash([6 * ratio, 4 * ratio]);
          c.beginPath();
          hull.forEach((q, i) => (i ? c.lineTo : c.moveTo).call(c, ox + scale * q[0], oy + scale * q[1]));
          c.closePath();
          c.stroke();
          c.setLineDash([]);
          c.beginPath();
          p.points.forEach((q, i) => (i ? c.lineTo : c.moveTo).call(c, ox + scale * q[0], oy + scale * q[1]));
          c.stroke();
        }
        c.fillStyle = '#ffffff';
        for (const a of aircraft) {
          c.beginPath();
          c.arc(ox + scale * a[0], oy + scale * a[1], 5 * ratio, 0, 2 * Math.PI);
          c.fill();
        }
      }
    }
    updateEarth();
    body.dataset.mosaicTiles = String(shown);
    body.dataset.mosaicFrame = m ? m.frame : '';  // a submap's name, or "earth"
    // From a picture's sending on the aircraft to its tile at the viewer: the median so far.
    body.dataset.mosaicLatency = m && m.latency_median_s >= 0 ? m.latency_median_s.toFixed(2) : '';
    // Drawn pixels (a test's proof that the view is not blank): the background is #10141a.
    const pixels = c.getImageData(0, 0, width, height).data;
    let drawn = 0;
    for (let i = 0; i < pixels.length; i += 4) {
      if (Math.abs(pixels[i] - 16) + Math.abs(pixels[i + 1] - 20) + Math.abs(pixels[i + 2] - 26) > 24) ++drawn;
    }
    body.dataset.mosaicDrawnPixels = String(drawn);
  }

  function convexHull(points) {  // Andrew's monotone chain
    const p = points.slice().sort((a, b) => a[0] - b[0] || a[1] - b[1]);
    if (p.length < 3) return p;
    const cross = (o, a, b) => (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    const lower = [], upper = [];
    for (const q of p) {
      while (lower.length >= 2 && cross(lower[lower.length - 2], lower[lower.length - 1], q) <= 0) lower.pop();
      lower.push(q);
    }
    for (let i = p.length - 1; i >= 0; --i) {
      while (upper.length >= 2 && cross(upper[upper.length - 2], upper[upper.length - 1], p[i]) <= 0) upper.pop();
      upper.push(p[i]);
    }
    return lower.slice(0, -1).concat(upper.slice(0, -1));
  }

  function setMosaicView(on) {
    showMosaic = on;
    canvas.hidden = on;
    mosaicCanvas.hidden = !on;
    document.getElementById('mosaic-view').setAttribute('aria-pressed', String(on));
    body.dataset.view = on ? 'mosaic' : '3d';
    if (on) requestMosaicDraw();
  }

  // --- North and the scale in metres, where the fixes place the largest merged map -------------
  let mosaicFrame = null;  // the mosaic view as drawn last: its ground_from_map and canvas pixels per mosaic pixel

  // The longest round length (1, 2 or 5 times a power of ten) of at most `metres`.
  function roundLength(metres) {
    const power = Math.pow(10, Math.floor(Math.log10(metres)));
    for (const f of [5, 2, 1]) if (f * power <= metres) return f * power;
    return power;
  }

  function lengthText(metres) {
    if (metres >= 1000) return String(metres / 1000) + ' km';
    if (metres >= 1) return String(metres) + ' m';
    return String(Math.round(metres * 100)) + ' cm';
  }

  // Map units per CSS pixel at the view's centre, and north's direction on the screen (degrees
  // clockwise from up), in the view shown.
  function viewScale(north) {
    if (showMosaic) {
      if (!mosaicFrame) return null;
      const g = mosaicFrame.ground_from_map, ratio = window.devicePixelRatio || 1;
      const n = rotate(g.rotation_wxyz, north);
      return { unitsPerPixel: ratio * mosaicFrame.gsd / (g.scale * mosaicFrame.scale),
               northDeg: Math.atan2(n[0], n[1]) * 180 / Math.PI };
    }
    const height = Math.max(1, canvas.clientHeight), width = Math.max(1, canvas.clientWidth);
    const distance = camera.position.distanceTo(controls.target);
    const unitsPerPixel = 2 * distance * Math.tan(camera.fov * Math.PI / 360) / height;
    const a = controls.target.clone().project(camera);
    const b = controls.target.clone().add(new THREE.Vector3(north[0], north[1], north[2]).multiplyScalar(0.05 * distance)).project(camera);
    const dx = (b.x - a.x) * width / 2, dy = -(b.y - a.y) * height / 2;  // screen pixels, y down
    return { unitsPerPixel: unitsPerPixel, northDeg: Math.atan2(dx, -dy) * 180 / Math.PI };
  }

  // Called every frame the 3D view draws: the page is written only where what it shows changed.
  let earthShown = '';  // the bar's width, its length and north's angle as last written ('': hidden)
  function updateEarth() {
    const box = document.getElementById('earth');
    const shown = earth && viewScale(earth.north);
    if (!shown || !(shown.unitsPerPixel > 0) || !isFinite(shown.unitsPerPixel)) {
      if (earthShown !== '') {
        box.hidden = true;
        delete body.dataset.scaleMetres;
        earthShown = '';
      }
      return;
    }
    const metresPerPixel = shown.unitsPerPixel * earth.metres_per_unit;
    const metres = roundLength(120 * metresPerPixel);
    const width = (metres / metresPerPixel).toFixed(1), angle = shown.northDeg.toFixed(1);
    const state = width + ' ' + metres + ' ' + angle;
    if (state === earthShown) return;
    earthShown = state;
    box.hidden = false;
    document.getElementById('scale-line').style.width = width + 'px';
    document.getElementById('scale-label').textContent = lengthText(metres);
    document.getElementById('north-arrow').setAttribute('transform', 'rotate(' + angle + ')');
    body.dataset.scaleMetres = String(metres);  // for tests
    body.dataset.northDeg = shown.northDeg.toFixed(0);
  }

  // --- Updates -------------------------------------------------------------------------------
  function applyLive(update) {
    live = update;
    showLive();
    updateFrustum();
    updateMosaicTiles();
  }

  function applyMap(update) {
    map = update;
    earth = (map.on_earth || []).find((e) => e.component === 0) || null;
    estimateUp();
    layoutComponents();
    rebuildTrajectories();
    rebuildPoints();
    showMap();
    updateFrustum();
    if (needsFit && sceneScale()) {
      fitView(false);
      needsFit = !points;
    }
    renderNow();
  }

  function applyCloud(buffer) {
    const header = new DataView(buffer, 0, 16);
    if (buffer.byteLength < 16 || header.getUint32(0, true) !== 0x4c435453) throw new Error('not a map cloud');
    const n = header.getUint32(8, true);
    if (buffer.byteLength < 16 + 16 * n) throw new Error('a map cloud cut short');
    cloud = {
      positions: new Float32Array(buffer, 16, 3 * n),
      colours: new Uint8Array(buffer, 16 + 12 * n, 3 * n),
      components: new Uint8Array(buffer, 16 + 15 * n, n),
    };
    layoutComponents();
    rebuildTrajectories();
    rebuildPoints();
    document.getElementById('point-count').textContent = String(n);
    body.dataset.points = String(n);
    if (needsFit && sceneScale()) {
      fitView(false);
      needsFit = false;
    }
    renderNow();
  }

  function onMessage(event) {
    body.dataset.updates = String(Number(body.dataset.updates) + 1);
    if (typeof event.data === 'string') {
      const update = JSON.parse(event.data);
      if (update.type === 'live') applyLive(update);
      else if (update.type === 'map') applyMap(update);
    } else {
      applyCloud(event.data);
    }
  }

  function setConnection(state) {
    body.dataset.ws = state;
    document.getElementById('connection').textContent =
        state === 'open' ? 'live' : state === 'closed' ? 'no connection to the ground station; retrying' : state;
  }

  function connect() {
    const socket = new WebSocket('ws://' + window.location.host + '/live');
    socket.binaryType = 'arraybuffer';
    socket.onopen = () => setConnection('open');
    socket.onmessage = (event) => {
      try {
        onMessage(event);
      } catch (e) {
        noteError(String(e));
      }
    };
    socket.onclose = () => {
      setConnection('closed');
      window.setTimeout(connect, 2000);
    };
  }

  // The state as it is now, then the pushes.
  async function start() {
    const state = await (await fetch('/state.json')).json();
    applyMap(state.map);
    applyLive(state.live);
    applyCloud(await (await fetch('/cloud.bin')).arrayBuffer());
    body.dataset.loaded = 'yes';
    connect();
  }

  document.getElementById('follow').addEventListener('click', (event) => {
    follow = !follow;
    event.target.setAttribute('aria-pressed', String(follow));
  });
  document.getElementById('top-view').addEventListener('click', () => fitView(true));
  document.getElementById('fit').addEventListener('click', () => fitView(false));
  document.getElementById('mosaic-view').addEventListener('click', () => setMosaicView(!showMosaic));
  setMosaicView(showMosaic);

  // Drawn pixels, counted when the map or the points change (a test's proof that the canvas is
  // not blank; reading the pixels back stalls the GPU, so never every frame).
  const gl = renderer.getContext();
  function countDrawnPixels() {
    const width = gl.drawingBufferWidth, height = gl.drawingBufferHeight;
    const pixels = new Uint8Array(4 * width * height);
    gl.readPixels(0, 0, width, height, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    const r = Math.round(background.r * 255), g = Math.round(background.g * 255), b = Math.round(background.b * 255);
    let drawn = 0;
    for (let i = 0; i < pixels.length; i += 4) {
      if (Math.abs(pixels[i] - r) + Math.abs(pixels[i + 1] - g) + Math.abs(pixels[i + 2] - b) > 24) ++drawn;
    }
    body.dataset.drawnPixels = String(drawn);
  }

  // The view's own frame rate (rendering included), shown beside the buttons: how responsive the
  // page is with the points it holds.
  const frameTimes = [];
  function noteFrame(time) {
    frameTimes.push(time);
    while (frameTimes.length > 30) frameTimes.shift();
    if (frameTimes.length >= 2 && frameTimes.length % 10 === 0) {
      const fps = 1000 * (frameTimes.length - 1) / (frameTimes[frameTimes.length - 1] - frameTimes[0]);
      body.dataset.viewFps = fps.toFixed(1);
      document.getElementById('view-fps').textContent = fps.toFixed(0) + ' fps';
    }
  }

  function frame(time) {
    if (!showMosaic) {
      resize();
      controls.update();
      renderer.render(scene, camera);
      updateEarth();
    }
    noteFrame(time);
    window.requestAnimationFrame(frame);
  }

  // Drawn at once when the map or the points change, and counted.
  function renderNow() {
    if (showMosaic) return;
    resize();
    renderer.render(scene, camera);
    updateEarth();
    countDrawnPixels();
  }
  window.requestAnimationFrame(frame);
  start().catch((e) => noteError('loading the state failed: ' + String(e)));
})();
