#!/usr/bin/env python3
"""Tables of scripts/poweron.sh: per simulated IMU, mean AOE over its power-ons (adapted: over
power-ons 2…N, the ones it was not adapted on), and the adaptation's verdict.

usage: poweron_table.py WORK_DIR OUT.json OUT.md  (OUT.md: the table replaces the text
between `<!-- poweron:begin -->` and `<!-- poweron:end -->`)."""
import glob
import json
import os
import statistics
import sys


def main():
    work, out_json, out_md = sys.argv[1:4]
    rows = []
    for ev in sorted(glob.glob(os.path.join(work, '*.eval.json'))):
        imu = os.path.basename(ev)[:-len('.eval.json')]
        table = json.load(open(ev))
        table = table['rows'] if isinstance(table, dict) else table
        by = {}
        for r in table:
            if r.get('aoe_deg') is None:
                continue
            k = int(r['bag'].rsplit('-', 1)[1])
            m = r['method']
            m = 'adapted' if m.endswith('-adapted') else 'alone' if m.endswith('-alone') else 'past' if m.endswith('-past') else m
            by.setdefault(m, {})[k] = r['aoe_deg']
        adapt_log = open(os.path.join(work, imu + '.adapt.log')).read().strip().splitlines()
        verdict = adapt_log[-1] if adapt_log else ''
        alone_log = os.path.join(work, imu + '.alone.adapt.log')
        alone_log = open(alone_log).read().strip().splitlines() if os.path.exists(alone_log) else []
        alone_verdict = alone_log[-1] if alone_log else ''
        past_log = os.path.join(work, imu + '.past.adapt.log')
        past_log = open(past_log).read().strip().splitlines() if os.path.exists(past_log) else []
        others = sorted(k for k in by.get('raw', {}) if k > 1)
        rested = [k for k in others if k in by.get('static-bias', {})]
        unrested = [k for k in others if k not in rested]
        mean = lambda m, ks: statistics.mean(by[m][k] for k in ks) if ks and m in by and all(k in by[m] for k in ks) else None
        row = {'imu': imu, 'power_ons': len(by.get('raw', {})), 'with_rest': rested, 'without_rest': unrested, 'adapt_verdict': verdict,
               'alone_verdict': alone_verdict, 'past_verdict': past_log[-1] if past_log else ''}
        # Adapted on power-on 2, judged on 1: scored on 3–N with a rest (held out).
        later = [k for k in rested if k > 2]
        row['held_out'] = {'power_ons': later, 'power_on_bias': mean('power-on-bias', later), 'static_bias': mean('static-bias', later),
                           'adapted': mean('past', later)}
        for name, ks in (('rest', rested), ('no_rest', unrested)):
            row[name] = {
                'raw': mean('raw', ks),
                'static_bias': mean('static-bias', ks),
                'power_on_bias': mean('power-on-bias', ks),
                'model_alone': mean('fsda-f', ks),
                'model_deployed': mean('fsda-f as deployed', ks),
                'adapted': mean('adapted', ks),
                'alone': mean('alone', ks),
            }
        rows.append(row)
    json.dump(rows, open(out_json, 'w'), indent=1)
    f = lambda v: '–' if v is None else f'{v:.2f}'
    lines = ['| IMU (profile-grade) | power-ons 2–N with a rest | raw | static-bias | power-on bias | bundled alone | bundled as deployed | adapted on power-on 1 (`--judge`) | adapted on power-on 1 alone (no judge) | without a rest: raw / as deployed / adapted / alone | adapted on power-on 2, judged on 1, on 3–N with a rest (held out): power-on bias / adapted |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        a, b = r['rest'], r['no_rest']
        ad = lambda d, k='adapted': f(d[k]) if d[k] is not None else 'refused'
        lines.append(f"| {r['imu']} | {len(r['with_rest'])} | {f(a['raw'])} | {f(a['static_bias'])} | {f(a['power_on_bias'])} | {f(a['model_alone'])} | {f(a['model_deployed'])} | {ad(a)} | {ad(a, 'alone')} | {f(b['raw'])} / {f(b['model_deployed'])} / {ad(b)} / {ad(b, 'alone')} | {f(r['held_out']['power_on_bias'])} / {ad(r['held_out'])} |")
    lines.append('')
    lines.append('Adaptation verdicts (`adapt --judge` on power-ons 2–N):')
    lines.append('')
    for r in rows:
        lines.append(f"- {r['imu']}: {r['adapt_verdict'].replace('error: ', '')}")
    lines.append('')
    lines.append('Without `--judge` (power-on 1 alone, as the node\'s `~/adapt`):')
    lines.append('')
    for r in rows:
        lines.append(f"- {r['imu']}: {r['alone_verdict'].replace('error: ', '')}")
    lines.append('')
    lines.append('Adapted on power-on 2, judged on power-on 1 (as the node\'s `adapt_support_archive` on its second power-on):')
    lines.append('')
    for r in rows:
        lines.append(f"- {r['imu']}: {r['past_verdict'].replace('error: ', '')}")
    table = '\n'.join(lines)
    text = open(out_md).read()
    a, b = '<!-- poweron:begin -->', '<!-- poweron:end -->'
    head, rest = text.split(a, 1)
    _, tail = rest.split(b, 1)
    open(out_md, 'w').write(head + a + '\n' + table + '\n' + b + tail)


if __name__ == '__main__':
    main()
