// A small static file server for the viewer page, on the loopback interface only.
//
//   /               this folder (index.html, viewer.js)
//   /node_modules/  the npm install prefix's node_modules (three, Spark)
//   /data/          the folder with the user's files (PLY, orbit.json, renders)
//
// As a program (scripts/view.sh uses it):
//   node server.mjs --modules DIR --data DIR --ply NAME [--camera NAME] [--bg r,g,b] [--port N]
// prints the page's URL and serves until stopped.
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));

const types = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.json': 'application/json',
  '.map': 'application/json',
  '.css': 'text/css',
  '.png': 'image/png',
  '.wasm': 'application/wasm',
};

// mounts: [[urlPrefix ending in '/', directory], ...], longest prefix first.
export function startServer({ modules, data, port = 0, host = '127.0.0.1' }) {
  const mounts = [['/node_modules/', modules], ['/data/', data], ['/', here]]
    .filter(([, dir]) => dir)
    .map(([prefix, dir]) => [prefix, path.resolve(dir)]);
  const server = http.createServer((req, res) => {
    const send = (code, text) => {
      res.writeHead(code, { 'content-type': 'text/plain' });
      res.end(text);
    };
    if (req.method !== 'GET' && req.method !== 'HEAD') return send(405, 'method not allowed');
    let urlPath;
    try {
      urlPath = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
    } catch {
      return send(400, 'bad path');
    }
    if (urlPath === '/') urlPath = '/index.html';
    const mount = mounts.find(([prefix]) => urlPath.startsWith(prefix));
    if (!mount) return send(404, 'not found');
    const [prefix, root] = mount;
    const file = path.resolve(root, '.' + path.posix.normalize('/' + urlPath.slice(prefix.length)));
    if (file !== root && !file.startsWith(root + path.sep)) return send(403, 'outside the served folder');
    fs.stat(file, (err, st) => {
      if (err || !st.isFile()) return send(404, `not found: ${urlPath}`);
      res.writeHead(200, {
        'content-type': types[path.extname(file).toLowerCase()] || 'application/octet-stream',
        'content-length': st.size,
        'cache-control': 'no-store',
      });
      if (req.method === 'HEAD') return res.end();
      fs.createReadStream(file).pipe(res);
    });
  });
  return new Promise((resolve, reject) => {
    server.once('error', reject);
    server.listen(port, host, () => {
      const { port: p } = server.address();
      resolve({ server, origin: `http://${host}:${p}` });
    });
  });
}

export function parseArgs(argv, known) {
  const out = {};
  for (let i = 0; i < argv.length; ++i) {
    const flag = argv[i];
    if (!flag.startsWith('--') || !known.includes(flag.slice(2))) throw new Error(`unknown argument '${flag}'`);
    if (i + 1 >= argv.length) throw new Error(`${flag} needs a value`);
    out[flag.slice(2)] = argv[++i];
  }
  return out;
}

export function pageQuery(params) {
  const q = new URLSearchParams();
  for (const [k, v] of Object.entries(params)) if (v !== undefined && v !== null) q.set(k, v);
  return q.toString().replace(/%2F/g, '/').replace(/%2C/g, ',');
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
  let args;
  try {
    args = parseArgs(process.argv.slice(2), ['modules', 'data', 'ply', 'camera', 'bg', 'port']);
    for (const k of ['modules', 'data', 'ply']) if (!args[k]) throw new Error(`--${k} is required`);
  } catch (e) {
    console.error(`server.mjs: ${e.message}`);
    process.exit(2);
  }
  const port = Number(args.port ?? 8080);
  if (!Number.isInteger(port) || port < 0 || port > 65535) {
    console.error(`server.mjs: --port must be 0..65535, got '${args.port}'`);
    process.exit(2);
  }
  startServer({ modules: args.modules, data: args.data, port })
    .then(({ origin }) => {
      const query = pageQuery({ ply: `/data/${args.ply}`, camera: args.camera && `/data/${args.camera}`, bg: args.bg });
      console.log(`viewer: open ${origin}/?${query}`);
      console.log('viewer: Ctrl-C stops the server');
    })
    .catch((e) => {
      console.error(`server.mjs: cannot listen on 127.0.0.1:${port}: ${e.message}`);
      process.exit(1);
    });
}
