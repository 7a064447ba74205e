#!/usr/bin/env python3
"""Tables of scripts/poweron_euroc.sh: per support recording, what `adapt` kept and the mean
AOE over the other recordings that start with a rest (static-bias exists there).

usage: poweron_euroc_table.py WORK_DIR OUT.json OUT.md  (OUT.md: each set's table replaces the
text between `<!-- euroc-adapt-SET:begin -->` and `<!-- euroc-adapt-SET:end -->`)."""
import json
import os
import re
import statistics
import sys


def load_report(path):
    try:
        text = open(path).read()
        return json.loads(text) if text.strip() else None
    except (OSError, json.JSONDecodeError):
        return None


def judged_after(entries):
    return {os.path.basename(j['recording']).removesuffix('.mcap'): j['after']['aoe_deg'] for j in entries}


def set_rows(work, name):
    ev = json.load(open(os.path.join(work, name + '.eval.json')))['rows']
    by = {}
    for r in ev:
        if r.get('aoe_deg') is not None:
            by.setdefault(r['method'], {})[r['bag']] = r['aoe_deg']
    bags = sorted(by['raw'])
    rested = [b for b in bags if b in by.get('static-bias', {})]
    rows = []
    for s in bags:
        report = load_report(os.path.join(work, name, s + '.adapt.json'))
        log = open(os.path.join(work, name, s + '.adapt.log')).read().strip().splitlines()
        others = [b for b in rested if b != s]
        mean = lambda d: statistics.mean(d[b] for b in others) if d is not None and all(b in d for b in others) else None
        row = {'support': s, 'others_with_rest': others, 'verdict': log[-1] if log else '',
               'static_bias': mean(by['static-bias']), 'power_on_bias': mean(by['power-on-bias'])}
        if report:
            kind = report.get('kind')
            row['kept'] = kind if report.get('accepted') else None
            cal = report.get('calibration')
            determined = cal and any(any(row_kept) for row_kept in cal['kept'])
            row['calibration_diagonal_percent'] = [100 * (cal['matrix'][k][k] - 1) for k in range(3)] if determined else None
            row['offset_rad_s'] = cal['leftover_bias_rad_s'] if cal and report.get('query_calibrated_with_offset') else None
            # `judged` holds the candidate kept (or, when refused, the one tried first: the
            # calibration alone, then with the bias offset in motion, then the networks).
            first_kind = kind or next(k for k, q in (('calibration', 'query_calibrated'),
                                                    ('calibration_with_offset', 'query_calibrated_with_offset'),
                                                    ('network', 'query_after')) if report.get(q))
            per = {first_kind: judged_after(report.get('judged', []))}
            for other in report.get('judged_others', []):
                per[other['kind']] = judged_after(other['judged'])
            row['calibration'] = mean(per.get('calibration') or None)
            row['calibration_with_offset'] = mean(per.get('calibration_with_offset') or None)
            row['networks'] = mean(per.get('network') or None)
            row['calibration_refused'] = report.get('calibration_refused')
            row['carry_over'] = report.get('carry_over')
        else:
            row['kept'] = None
        row['deployed'] = row.get(row['kept'] if row['kept'] != 'network' else 'networks') if row['kept'] else row['power_on_bias']
        # Adapted on the support alone (no --judge): what it kept, run on the others as deployed.
        alone = load_report(os.path.join(work, name, s + '.alone.adapt.json'))
        row['alone_kept'] = alone.get('kind') if alone and alone.get('accepted') else None
        row['alone_pieces'] = alone.get('query_calibrated_pieces') if alone else None
        alone_eval = os.path.join(work, name, s + '.alone.eval.json')
        if row['alone_kept'] and os.path.exists(alone_eval):
            model_rows = {r['bag']: r['aoe_deg'] for r in json.load(open(alone_eval))['rows'] if r.get('aoe_deg') is not None}
            row['alone_deployed'] = mean(model_rows)
        else:
            row['alone_deployed'] = row['power_on_bias']
        rows.append(row)
    return rows


def short(why):
    if 'beyond any gyro' in why:
        return why.split(' departs')[0] + ' ' + why.split('departs from I by ')[1].split(',')[0] + ' (implausible)'
    if 'no scale or cross-axis' in why:
        return 'nothing determined'
    return why[:50]


def table(rows):
    f = lambda v: '–' if v is None else f'{v:.2f}'
    out = ['| support (adapted on its first 60 s) | kept | Ĉ_ω diagonal − 1 (%) | bias offset in motion (mrad/s) | carried over: ratio (95 % bound) over the 10 others | static-bias | power-on bias | gyro calibration alone | with the offset | adapted networks | as deployed after `adapt` | without `--judge`: kept (query pieces: ratio, bound) | as deployed after `adapt` without `--judge` |',
           '|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    names = {'calibration': 'gyro calibration', 'calibration_with_offset': 'calibration with the offset', 'network': 'networks'}
    for r in rows:
        kept = names.get(r['kept'], 'refused')
        if r['kept'] is None:
            v = r['verdict']
            kept += ': ' + ('no standstill in the support' if 'no standstill' in v else 'not better on the other power-ons' if 'other recordings' in v else 'not better on the query' if 'query' in v else v[:60])
        diag = r.get('calibration_diagonal_percent')
        diag = ' / '.join(f'{d:+.2f}' for d in diag) if diag else ('none: ' + short(r['calibration_refused']) if r.get('calibration_refused') else '–')
        c = r.get('carry_over')
        ratio = f"{c['ratio']:.3f} (≤ {c['upper_95']:.3f})" if c else '–'
        alone = names.get(r.get('alone_kept'), 'refused')
        p = r.get('alone_pieces')
        alone += f" ({p['ratio']:.2f}, ≤ {p['upper_95']:.2f})" if p else ''
        offset = r.get('offset_rad_s')
        offset = ' / '.join(f'{1e3 * b:+.2f}' for b in offset) if offset else '–'
        out.append(f"| {r['support']} | {kept} | {diag} | {offset} | {ratio} | {f(r['static_bias'])} | {f(r['power_on_bias'])} | {f(r.get('calibration'))} | {f(r.get('calibration_with_offset'))} | {f(r.get('networks'))} | {f(r['deployed'])} | {alone} | {f(r.get('alone_deployed'))} |")
    return '\n'.join(out)


def main():
    work, out_json, out_md = sys.argv[1:4]
    result = {name: set_rows(work, name) for name in ('recorded', 'injected')}
    json.dump(result, open(out_json, 'w'), indent=1)
    md = open(out_md).read()
    for name, rows in result.items():
        begin, end = f'<!-- euroc-adapt-{name}:begin -->', f'<!-- euroc-adapt-{name}:end -->'
        md = re.sub(re.escape(begin) + '.*?' + re.escape(end), lambda _: f'{begin}\n{table(rows)}\n{end}', md, flags=re.S)
    open(out_md, 'w').write(md)


if __name__ == '__main__':
    main()
