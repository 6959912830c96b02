/* The zoomable report (ladrc_tools/offline/html_report.py): decode the embedded streams,
 * rebuild the min/max levels of the raw curves, draw uPlot charts with linked time axes and
 * pick, on every zoom, the finest level with at most meta.pointsPerPx points per pixel.
 * Stream format: ladrc_tools/offline/codec.py; the pyramid rule: offline/pyramid.py. */
(function () {
  'use strict';
  const meta = JSON.parse(document.getElementById('ladrc-meta').textContent);
  const statusEl = document.getElementById('status');
  const errors = [];
  const api = {meta: meta, errors: errors, plots: {}, timing: {}, window: null, level: null};
  window.ladrcReport = api;
  window.addEventListener('error', (e) => errors.push(String(e.message || e)));
  window.addEventListener('unhandledrejection', (e) => errors.push(String(e.reason)));

  const F = meta.factor;
  const now = () => performance.now();
  const t0ms = now();

  // ---- the blob and its streams -------------------------------------------------------
  function base64Bytes(text) {
    if (typeof Uint8Array.fromBase64 === 'function') return Uint8Array.fromBase64(text);
    const bin = atob(text);
    const out = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out;
  }

  async function inflate(bytes) {
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }

  // One QuantEncoder stream -> Float64Array of its values (NaN / +-Infinity kept).
  function decodeValues(buf, res) {
    let p = 0;
    const rd = () => {
      let v = 0, mul = 1, b;
      do { b = buf[p++]; v += (b & 127) * mul; mul *= 128; } while (b & 128);
      return v;
    };
    const blocks = [];
    let total = 0;
    let qa = 0, qb = 0;  // the last two quantised values
    while (p < buf.length) {
      const count = rd(), order = rd(), g = rd(), nruns = rd();
      const runs = [];
      for (let r = 0; r < nruns; r++) runs.push([rd(), rd(), rd()]);
      const out = new Float64Array(count);
      for (let i = 0; i < count; i++) {
        const z = rd();
        const d = (z % 2 === 1 ? -(z + 1) / 2 : z / 2) * g;
        const q = order === 1 ? qb + d : 2 * qb - qa + d;
        qa = qb; qb = q;
        out[i] = q * res;
      }
      for (const [start, len, kind] of runs) {
        out.fill(kind === 1 ? NaN : kind === 2 ? Infinity : -Infinity, start, start + len);
      }
      blocks.push(out);
      total += count;
    }
    if (blocks.length === 1) return blocks[0];
    const all = new Float64Array(total);
    let o = 0;
    for (const b of blocks) { all.set(b, o); o += b.length; }
    return all;
  }

  // ---- min/max levels (the rule of offline/pyramid.py) --------------------------------
  // A level: {level, s (samples per bucket), first, second (the extremes in the order they
  // occurred), lo, hi, mf (kept while the next level is built)}.
  function levelFromSamples(y, level) {
    const s = Math.pow(F, level), n = y.length, nb = Math.ceil(n / s);
    const lo = new Float64Array(nb), hi = new Float64Array(nb), mf = new Uint8Array(nb);
    for (let b = 0; b < nb; b++) {
      const a = b * s, e = Math.min(a + s, n);
      let vlo = Infinity, vhi = -Infinity, ilo = a, ihi = a, empty = true;
      {
        const v = y[a];
        if (v === v) { empty = false; vlo = v; vhi = v; }
      }
      for (let i = a + 1; i < e; i++) {
        const v = y[i];
        if (v !== v) continue;
        empty = false;
        if (v < vlo) { vlo = v; ilo = i; }
        if (v > vhi) { vhi = v; ihi = i; }
      }
      if (empty) { lo[b] = NaN; hi[b] = NaN; mf[b] = 0; } else {
        lo[b] = vlo; hi[b] = vhi; mf[b] = ihi < ilo ? 1 : 0;
      }
    }
    return finishLevel({level: level, s: s, lo: lo, hi: hi, mf: mf});
  }

  function levelFromChildren(c) {
    const nc = c.lo.length, nb = Math.ceil(nc / F);
    const lo = new Float64Array(nb), hi = new Float64Array(nb), mf = new Uint8Array(nb);
    for (let b = 0; b < nb; b++) {
      const a = b * F, e = Math.min(a + F, nc);
      let vlo = Infinity, vhi = -Infinity, ilo = a, ihi = a, empty = true;
      {
        const l = c.lo[a], h = c.hi[a];
        if (l === l) { empty = false; vlo = l; vhi = h; }
      }
      for (let i = a + 1; i < e; i++) {
        const l = c.lo[i], h = c.hi[i];
        if (l !== l) continue;
        empty = false;
        if (l < vlo) { vlo = l; ilo = i; }
        if (h > vhi) { vhi = h; ihi = i; }
      }
      if (empty) { lo[b] = NaN; hi[b] = NaN; mf[b] = 0; } else {
        lo[b] = vlo; hi[b] = vhi;
        mf[b] = ilo === ihi ? c.mf[ilo] : (ihi < ilo ? 1 : 0);
      }
    }
    return finishLevel({level: c.level + 1, s: c.s * F, lo: lo, hi: hi, mf: mf});
  }

  function finishLevel(L) {
    const nb = L.lo.length;
    L.first = new Float64Array(nb);
    L.second = new Float64Array(nb);
    for (let b = 0; b < nb; b++) {
      L.first[b] = L.mf[b] ? L.hi[b] : L.lo[b];
      L.second[b] = L.mf[b] ? L.lo[b] : L.hi[b];
    }
    return L;
  }

  function pyramidOf(y) {
    const levels = [];
    if (y.length === 0) return levels;
    let L = levelFromSamples(y, 1);
    levels.push(L);
    while (L.lo.length > meta.topBuckets) {
      const next = levelFromChildren(L);
      delete L.lo; delete L.hi; delete L.mf;
      levels.push(next);
      L = next;
    }
    return levels;
  }

  function storedLevels(list, base) {
    return list.map((pairs, k) => {
      const nb = pairs.length / 2;
      const first = new Float64Array(nb), second = new Float64Array(nb);
      for (let b = 0; b < nb; b++) { first[b] = pairs[2 * b]; second[b] = pairs[2 * b + 1]; }
      return {level: base + k, s: Math.pow(F, base + k), first: first, second: second};
    });
  }

  // ---- curves -------------------------------------------------------------------------
  let T = null;  // the time of every sample [s]
  const curves = {};  // key -> {key, meta, raw | steps | levels, finest, coarsest}

  function lowerBound(a, x) { let lo = 0, hi = a.length; while (lo < hi) { const m = (lo + hi) >> 1; if (a[m] < x) lo = m + 1; else hi = m; } return lo; }
  function upperBound(a, x) { let lo = 0, hi = a.length; while (lo < hi) { const m = (lo + hi) >> 1; if (a[m] <= x) lo = m + 1; else hi = m; } return lo; }

  // The points of one curve at `level` for samples i0..i1: {idx: sample indices, y: values}.
  function extract(c, level, i0, i1) {
    const idx = [], y = [];
    const n = T.length;
    if (i1 < i0) return {idx: idx, y: y};
    if (level === 0) {
      if (c.raw) {
        for (let i = i0; i <= i1; i++) { idx.push(i); y.push(c.raw[i]); }
      } else {  // steps: the value last changed to
        let k = upperBound(c.steps.index, i0) - 1;
        for (let i = i0; i <= i1; i++) {
          while (k + 1 < c.steps.index.length && c.steps.index[k + 1] <= i) k++;
          idx.push(i); y.push(k >= 0 ? c.steps.value[k] : NaN);
        }
      }
      return {idx: idx, y: y};
    }
    const s = Math.pow(F, level);
    const b0 = Math.floor(i0 / s), b1 = Math.floor(i1 / s);
    if (c.steps) return stepsBuckets(c, s, b0, b1);
    const L = c.levels[level - c.levels[0].level];
    for (let b = b0; b <= b1 && b < L.first.length; b++) {
      const a = b * s, e = Math.min((b + 1) * s, n) - 1;
      idx.push(a); y.push(L.first[b]);
      if (e > a) { idx.push(e); y.push(L.second[b]); }
    }
    return {idx: idx, y: y};
  }

  // Min/max of a step curve over buckets, from its change points (exact, any level).
  function stepsBuckets(c, s, b0, b1) {
    const idx = [], y = [];
    const ci = c.steps.index, cv = c.steps.value, n = T.length;
    let k = upperBound(ci, b0 * s) - 1;
    for (let b = b0; b <= b1; b++) {
      const a = b * s, e = Math.min((b + 1) * s, n) - 1;
      while (k + 1 < ci.length && ci[k + 1] <= a) k++;
      let v = k >= 0 ? cv[k] : NaN;
      let vlo = v === v ? v : Infinity, vhi = v === v ? v : -Infinity, ilo = a, ihi = a;
      let empty = v !== v;
      while (k + 1 < ci.length && ci[k + 1] <= e) {
        k++;
        v = cv[k];
        if (v !== v) continue;
        if (empty) { empty = false; vlo = v; vhi = v; ilo = ci[k]; ihi = ci[k]; continue; }
        if (v < vlo) { vlo = v; ilo = ci[k]; }
        if (v > vhi) { vhi = v; ihi = ci[k]; }
      }
      const mf = !empty && ihi < ilo;
      const first = empty ? NaN : (mf ? vhi : vlo), second = empty ? NaN : (mf ? vlo : vhi);
      idx.push(a); y.push(first);
      if (e > a) { idx.push(e); y.push(second); }
    }
    return {idx: idx, y: y};
  }

  // ---- plots ----------------------------------------------------------------------------
  const PTS = meta.pointsPerPx;
  let plotWidth = 800;
  const history = [];
  let full = [0, 1];
  let busy = false;

  // the width the curves are drawn in (the plot less its axes), in CSS pixels
  function drawWidth() {
    const first = Object.values(api.plots)[0];
    return (first && first.u.over.clientWidth) || plotWidth;
  }

  function chooseLevel(nWin) {
    const budget = PTS * drawWidth();
    if (nWin <= budget) return 0;
    let level = 1;
    while (2 * Math.ceil(nWin / Math.pow(F, level)) > budget && level < 40) level++;
    return level;
  }

  function seriesLevel(c, level) {
    if (c.steps) return level;
    return Math.min(Math.max(level, c.finest), c.coarsest);
  }

  function plotData(p, level, i0, i1) {
    const parts = p.series.map((s) => {
      const c = curves[s.key];
      const lv = seriesLevel(c, level);
      return Object.assign({lv: lv}, extract(c, lv, i0, i1));
    });
    // the x of every point of every series (sample indices), sorted, once each
    let idx = parts[0].idx;
    const same = parts.every((q) => q.lv === parts[0].lv || (q.idx.length === idx.length && q.idx.every((v, i) => v === idx[i])));
    if (!same) {
      const set = new Set();
      for (const q of parts) for (const i of q.idx) set.add(i);
      idx = Array.from(set).sort((a, b) => a - b);
    }
    const pos = new Map();
    if (!same) idx.forEach((v, i) => pos.set(v, i));
    const data = [idx.map((i) => T[i])];
    parts.forEach((q, si) => {
      const s = p.series[si];
      const ys = same ? new Array(q.y.length) : new Array(idx.length).fill(undefined);
      for (let k = 0; k < q.y.length; k++) {
        let v = q.y[k];
        if (s.key === 'followed') v = v >= 0.5 ? -0.25 : null;
        else if (!Number.isFinite(v)) v = null;
        ys[same ? k : pos.get(q.idx[k])] = v;
      }
      data.push(ys);
    });
    p.levels = parts.map((q) => q.lv);
    return data;
  }

  function levelText(level) {
    if (level === 0) return 'every sample';
    return 'min/max of ' + Math.pow(F, level) + ' samples per bucket';
  }

  function drawWindow(t0, t1) {
    const i0 = lowerBound(T, t0), i1 = upperBound(T, t1) - 1;
    const level = chooseLevel(Math.max(0, i1 - i0 + 1));
    const j0 = Math.max(0, i0 - 1), j1 = Math.min(T.length - 1, i1 + 1);  // reach the edges
    api.level = level;  // before drawing: the points' show() reads it
    busy = true;
    try {
      for (const p of Object.values(api.plots)) {
        const data = plotData(p, level, j0, j1);
        p.u.batch(() => {
          p.u.setData(data, false);
          p.u.setScale('x', {min: t0, max: t1});
        });
      }
    } finally {
      busy = false;
    }
    api.window = [t0, t1];
    // the curves kept only as coarser min/max levels (a long run's ESO, TD, ...), named
    const coarse = new Map();
    for (const p of Object.values(api.plots)) {
      p.series.forEach((s, i) => {
        if (p.levels[i] > level) coarse.set(meta.curves[s.key].label, p.levels[i]);
      });
    }
    const span = t1 - t0;
    let text = 't = ' + t0.toFixed(4) + ' .. ' + t1.toFixed(4) + ' s (' +
      (span >= 1 ? span.toFixed(3) + ' s' : (span * 1e3).toFixed(2) + ' ms') + '): ' + levelText(level);
    if (coarse.size) {
      text += '; ' + Array.from(coarse.keys()).join(', ') + ': ' +
        levelText(Math.max(...coarse.values())) + ' (drawn with dots: stored no finer)';
    }
    document.getElementById('window').textContent = text;
  }

  function afterDraw() {
    return new Promise((resolve) => setTimeout(resolve, 0));
  }

  function zoom(t0, t1, remember) {
    t0 = Math.max(full[0], Number(t0));
    t1 = Math.min(full[1], Number(t1));
    if (!(t1 > t0)) { t0 = full[0]; t1 = full[1]; }
    if (remember !== false && api.window) history.push(api.window);
    drawWindow(t0, t1);
    return afterDraw();
  }
  api.zoom = (t0, t1) => zoom(t0, t1);
  api.reset = () => zoom(full[0], full[1]);
  api.back = () => (history.length ? zoom(...history.pop(), false) : afterDraw());

  // The points of a series inside the window: level, how many there are (null = a gap:
  // NaN in the bag) and how many are drawn.
  api.visible = (plotId, key) => {
    const p = api.plots[plotId];
    const si = p.series.findIndex((s) => s.key === key);
    const x = p.u.data[0], y = p.u.data[si + 1];
    const [t0, t1] = api.window;
    let points = 0, drawn = 0;
    for (let i = 0; i < x.length; i++) {
      if (x[i] < t0 || x[i] > t1 || y[i] === undefined) continue;
      points++;
      if (y[i] !== null) drawn++;
    }
    return {level: p.levels[si], points: points, drawn: drawn, window: api.window};
  };
  api.values = (plotId, key) => {
    const p = api.plots[plotId];
    const si = p.series.findIndex((s) => s.key === key);
    const x = [], y = [];
    const [t0, t1] = api.window;
    p.u.data[0].forEach((t, i) => {
      const v = p.u.data[si + 1][i];
      if (t >= t0 && t <= t1 && v !== undefined) { x.push(t); y.push(v); }
    });
    return {x: x, y: y};
  };
  api.pyramid = (key, level) => {  // the extremes of one level of a curve, in order
    const c = curves[key];
    const L = c.levels.find((l) => l.level === level);
    return L ? {samples: L.s, first: Array.from(L.first), second: Array.from(L.second)} : null;
  };

  function axisValues(u, splits) { return splits.map((v) => String(+v.toPrecision(6))); }

  // time ticks with as many decimals as their spacing needs (no thousands separator)
  function timeValues(u, splits, axisIdx, space, incr) {
    const dec = Math.max(0, Math.min(6, Math.ceil(-Math.log10(incr) - 1e-9)));
    return splits.map((v) => v.toFixed(dec));
  }

  function makePlot(p, el, width) {
    const series = [{label: 't [s]', value: (u, v) => v == null ? '--' : v.toFixed(4)}];
    for (const s of p.series) {
      const c = meta.curves[s.key];
      const opts = {
        label: c.label + (c.unit ? ' [' + c.unit + ']' : ''),
        stroke: s.color, width: s.width, spanGaps: false,
        // dots where the curve is drawn coarser than the window's level (stored no finer)
        points: {show: (u, si) => p.levels !== undefined && p.levels[si - 1] > api.level,
                 size: 5},
      };
      if (s.dash) opts.dash = [6, 4];
      if (s.stepped) opts.paths = uPlot.paths.stepped({align: 1});
      if (s.key === 'followed') opts.value = (u, v) => v == null ? 'no' : 'yes';
      if (s.key === 'state') opts.value = (u, v) => v == null ? '--' : (meta.states[v] || String(v));
      series.push(opts);
    }
    // one y-axis width for every plot (the state names need it), so the time axes line up
    const axes = [{label: 't [s]', values: timeValues, space: 90},
                  {label: p.y, values: axisValues, size: 110, labelSize: 30}];
    const scales = {x: {time: false, auto: false}};
    if (p.id === 'state') {
      const n = meta.states.length;
      scales.y = {auto: false, range: [-0.6, n - 0.4]};
      axes[1] = {size: 140, splits: () => meta.states.map((_, i) => i),
                 values: (u, splits) => splits.map((v) => meta.states[v] || '')};
    }
    const hooks = {
      setScale: [(u, key) => {
        // a zoom by the user (drag): redo every plot's data, after uPlot's own commit
        if (key === 'x' && !busy) {
          const [a, b] = [u.scales.x.min, u.scales.x.max];
          setTimeout(() => zoom(a, b), 0);
        }
      }],
      draw: [(u) => {
        p.draws = (p.draws || 0) + 1;
        if (meta.faults && meta.faults.length) {  // every fault of the run: a red line, F1...
          const ctx = u.ctx;
          ctx.save();
          ctx.strokeStyle = '#d62728';
          ctx.fillStyle = '#d62728';
          ctx.setLineDash([6, 3]);
          ctx.font = '12px sans-serif';
          for (const f of meta.faults) {
            const x = u.valToPos(f.t, 'x', true);
            if (x < u.bbox.left || x > u.bbox.left + u.bbox.width) continue;
            ctx.beginPath(); ctx.moveTo(x, u.bbox.top); ctx.lineTo(x, u.bbox.top + u.bbox.height); ctx.stroke();
            ctx.fillText(f.label, x + 3, u.bbox.top + 12);
          }
          ctx.restore();
        }
        if (p.id === 'command' && meta.vMax) {
          const ctx = u.ctx;
          ctx.save();
          ctx.strokeStyle = '#d62728';
          ctx.setLineDash([2, 4]);
          for (const v of [meta.vMax, -meta.vMax]) {
            const y = u.valToPos(v, 'y', true);
            if (y < u.bbox.top || y > u.bbox.top + u.bbox.height) continue;
            ctx.beginPath(); ctx.moveTo(u.bbox.left, y); ctx.lineTo(u.bbox.left + u.bbox.width, y); ctx.stroke();
          }
          ctx.restore();
        }
      }],
    };
    const opts = {
      title: p.title, width: width, height: p.id === 'state' ? 170 : 240,
      series: series, axes: axes, scales: scales, hooks: hooks,
      cursor: {sync: {key: 'ladrc'}, drag: {x: true, y: false, setScale: true},
               bind: {dblclick: () => () => { api.reset(); return null; }}},
      legend: {live: true},
    };
    const empty = [[]].concat(p.series.map(() => []));
    p.u = new uPlot(opts, empty, el);
    p.u.over.addEventListener('wheel', (e) => {
      e.preventDefault();
      const [a, b] = api.window;
      const span = b - a;
      if (e.shiftKey || Math.abs(e.deltaX) > Math.abs(e.deltaY)) {
        const d = Math.sign(e.deltaX || e.deltaY) * span * 0.15;
        const s0 = Math.min(Math.max(full[0], a + d), full[1] - span);
        zoom(s0, s0 + span);
        return;
      }
      const at = p.u.posToVal(e.offsetX, 'x');
      const k = e.deltaY > 0 ? 1.25 : 0.8;
      zoom(at - (at - a) * k, at + (b - at) * k);
    }, {passive: false});
  }

  function widthOf(container) {
    return Math.max(320, Math.floor(container.clientWidth || window.innerWidth - 40));
  }

  function describe() {
    const kinds = {raw: [], steps: [], aux: [], levels: []};
    for (const [key, c] of Object.entries(meta.curves)) {
      if (c.levels) kinds.levels.push(c.label); else kinds[c.kind].push(c.label);
    }
    let text = 'Stored: every sample of ' + (kinds.raw.concat(kinds.aux).join(', ') || 'none') +
      '; every change of ' + (kinds.steps.join(', ') || 'none');
    if (kinds.levels.length) {
      text += '; the min/max of buckets of ' + Math.pow(F, meta.auxLevel) + ' samples (and coarser) of ' + kinds.levels.join(', ') +
        ' (drawn at that resolution when zoomed further in)';
    }
    document.getElementById('stored').textContent = text + '.';
  }

  async function main() {
    const summary = document.getElementById('summary');
    for (const line of meta.summary) {
      const d = document.createElement('div'); d.textContent = line; summary.appendChild(d);
    }
    describe();
    const blob = base64Bytes(document.getElementById('ladrc-data').textContent);
    const t1ms = now();
    const raw = await Promise.all(meta.streams.map(([off, len]) => inflate(blob.subarray(off, off + len))));
    const t2ms = now();
    T = decodeValues(raw[meta.time.stream], meta.time.res);
    for (const [key, c] of Object.entries(meta.curves)) {
      const e = {key: key, meta: c};
      if (c.raw !== undefined) {
        e.raw = decodeValues(raw[c.raw], c.res);
        e.levels = pyramidOf(e.raw);
        e.finest = 0;
      } else if (c.index !== undefined) {
        e.steps = {index: decodeValues(raw[c.index], 1), value: decodeValues(raw[c.value], c.res)};
        e.finest = 0;
      } else {
        e.levels = storedLevels(c.levels.map((s) => decodeValues(raw[s], c.res)), c.base);
        e.finest = c.base;
      }
      e.coarsest = e.levels && e.levels.length ? e.levels[e.levels.length - 1].level : e.finest;
      curves[key] = e;
    }
    const t3ms = now();
    full = [T.length ? T[0] : 0, T.length ? T[T.length - 1] : 1];
    if (!(full[1] > full[0])) full = [full[0], full[0] + 1e-3];
    const container = document.getElementById('plots');
    plotWidth = widthOf(container);
    for (const p of meta.plots) {
      const el = document.createElement('div');
      el.className = 'plot';
      el.id = 'plot-' + p.id;
      container.appendChild(el);
      const entry = {id: p.id, title: p.title, y: p.y, series: p.series, draws: 0};
      api.plots[p.id] = entry;
      makePlot(entry, el, plotWidth);
    }
    drawWindow(full[0], full[1]);
    await afterDraw();
    statusEl.textContent = '';
    statusEl.style.display = 'none';
    api.timing = {base64_ms: t1ms - t0ms, inflate_ms: t2ms - t1ms, decode_ms: t3ms - t2ms,
                  draw_ms: now() - t3ms, total_ms: now() - t0ms,
                  ready_ms: now()};  // since the navigation started: load to every plot drawn
    let resizeTimer = null;
    window.addEventListener('resize', () => {
      clearTimeout(resizeTimer);
      resizeTimer = setTimeout(() => {
        plotWidth = widthOf(container);
        for (const p of Object.values(api.plots)) p.u.setSize({width: plotWidth, height: p.u.height});
        drawWindow(api.window[0], api.window[1]);
      }, 150);
    });
    document.getElementById('reset').addEventListener('click', () => api.reset());
    document.getElementById('back').addEventListener('click', () => api.back());
  }

  api.ready = main().then(() => {
    const undrawn = Object.values(api.plots).filter((p) => !p.draws).map((p) => p.id);
    if (undrawn.length) throw new Error('plots not drawn: ' + undrawn.join(', '));
    return Object.keys(api.plots);
  }).catch((err) => {
    statusEl.textContent = 'The report could not be drawn: ' + err;
    statusEl.className = 'error';
    console.error('ladrc report:', err);
    throw err;
  });
})();
