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
            m = 'adapted' if m.endswith('-adapted') else m
            by.setdefault(m, {})[k] = r['aoe_deg']
        adapt_log = open(os.path.join(work, imu + '.adapt.log')).read().strip().splitlines()
        verdict = adapt_log[-1] if adapt_log else ''
        others = sorted(k for k in by.get('raw', {}) if k > 1)
        mean = lambda m, ks: statistics.mean(by[m][k] for k in ks) if m in by and all(k in by[m] for k in ks) else None
        row = {
            'imu': imu,
            'power_ons': len(by.get('raw', {})),
            'with_rest': sorted(by.get('static-bias', {})),
            'raw': mean('raw', others),
            'static_bias': mean('static-bias', [k for k in others if k in by.get('static-bias', {})]) if by.get('static-bias') else None,
            'power_on_bias': mean('power-on-bias', others),
            'model_alone': mean('fsda-f', others),
            'model_deployed': mean('fsda-f as deployed', others),
            'adapted': mean('adapted', others),
            'adapt_verdict': verdict,
        }
        rows.append(row)
    json.dump(rows, open(out_json, 'w'), indent=1)
    f = lambda v: '–' if v is None else f'{v:.2f}'
    lines = ['| IMU (profile-grade) | power-ons with a rest | raw | static-bias (those with a rest) | power-on bias | bundled model alone | bundled as deployed | adapted on power-on 1 |',
             '|---|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f"| {r['imu']} | {len(r['with_rest'])} of {r['power_ons']} | {f(r['raw'])} | {f(r['static_bias'])} | {f(r['power_on_bias'])} | {f(r['model_alone'])} | {f(r['model_deployed'])} | {f(r['adapted']) if r['adapted'] is not None else 'rejected'} |")
    table = '\n'.join(lines)
    text = open(out_md).read()
    a, b = '<!-- poweron:begin -->', '<!-- poweron:end -->'
    head, rest = text.split(a, 1)
    _, tail = rest.split(b, 1)
    open(out_md, 'w').write(head + a + '\n' + table + '\n' + b + tail)


if __name__ == '__main__':
    main()
