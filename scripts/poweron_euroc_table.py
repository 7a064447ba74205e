#!/usr/bin/env python3
"""Tables of scripts/poweron_euroc.sh: per support recording, what `adapt` kept and the mean
AOE over the other recordings that start with a rest (static-bias exists there).

Then, per recording in EuRoC's order, what `adapt` kept when judged on the power-ons before it
and the mean AOE over the ones after it (held out: neither fitted nor judged).

usage: poweron_euroc_table.py WORK_DIR OUT.json OUT.md  (OUT.md: each set's tables replace the
text between `<!-- euroc-adapt-SET:begin -->` and `<!-- euroc-adapt-SET:end -->`, and between
`<!-- euroc-adapt-SET-past:begin -->` and `<!-- euroc-adapt-SET-past:end -->`; with MARKER_SUFFIX,
that suffix after SET and after SET-past)."""
import json
import os
import re
import statistics
import sys


# As scripts/poweron_euroc.sh's JUDGE_POWER_ONS (the node's adapt_judge_power_ons).
JUDGE_POWER_ONS = int(os.environ.get('JUDGE_POWER_ONS', '3'))
# `-100` for the run at 100 Hz (scripts/poweron_euroc.sh's RATE_HZ): its own markers.
MARKER_SUFFIX = os.environ.get('MARKER_SUFFIX', '')


def load_report(path):
    try:
        text = open(path).read()
        return json.loads(text) if text.strip() else None
    except (OSError, json.JSONDecodeError):
        return None


def judged_after(entries):
    return {os.path.basename(j['recording']).removesuffix('.mcap'): j['after']['aoe_deg'] for j in entries}


def set_rows(work, name):
    by = eval_rows(work, name)
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


def carried(c):
    """The carry-over ratio, its bound over the recordings and over the pieces (the one kept on)."""
    if not c:
        return '–'
    pieces = f"{c['piece_upper_95']:.3f}" if c.get('pieces', 0) >= 2 else 'none'
    return f"{c['ratio']:.3f} (≤ {c['upper_95']:.3f}; pieces ≤ {pieces})"


def eval_rows(work, name):
    by = {}
    for r in json.load(open(os.path.join(work, name + '.eval.json')))['rows']:
        if r.get('aoe_deg') is not None:
            by.setdefault(r['method'], {})[r['bag']] = r['aoe_deg']
    return by


def past_rows(work, name):
    """Each recording but the first and last, judged on those before it, scored on those after."""
    by = eval_rows(work, name)
    bags = sorted(by['raw'])
    rested = set(by.get('static-bias', {}))
    rows = []
    for i, s in enumerate(bags[1:-1], start=1):
        later = [b for b in bags[i + 1:] if b in rested]
        report = load_report(os.path.join(work, name, s + '.past.adapt.json'))
        log = open(os.path.join(work, name, s + '.past.adapt.log')).read().strip().splitlines()
        kept = report.get('kind') if report and report.get('accepted') else None
        row = {'support': s, 'judged_on': bags[max(0, i - JUDGE_POWER_ONS):i], 'later_with_rest': later, 'kept': kept,
               'verdict': log[-1] if log else '', 'carry_over': report.get('carry_over') if report else None}
        for key, method in (('static_bias', 'static-bias'), ('power_on_bias', 'power-on-bias')):
            row[key] = statistics.mean(by[method][b] for b in later) if later else None
        deployed = dict(by['power-on-bias'])
        ev = os.path.join(work, name, s + '.past.eval.json')
        if kept and os.path.exists(ev):
            deployed = {r['bag']: r['aoe_deg'] for r in json.load(open(ev))['rows'] if r.get('aoe_deg') is not None}
        row['deployed_per_recording'] = {b: deployed[b] for b in later}
        row['deployed'] = statistics.mean(deployed[b] for b in later) if later else None
        row['each'] = ', '.join(f"{deployed[b] / by['power-on-bias'][b]:.2f}" for b in later) if kept else '–'
        rows.append(row)
    return rows


def past_table(rows):
    f = lambda v: '–' if v is None else f'{v:.2f}'
    names = {'calibration': 'gyro calibration', 'calibration_with_offset': 'calibration with the offset', 'network': 'networks'}
    out = ['| power-on (adapted on its first 60 s) | judged on | kept | carried over on those: ratio (bounds) | later power-ons with a rest | static-bias | power-on bias | as deployed after `adapt` | as deployed / power-on bias, each later one |',
           '|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        kept = names.get(r['kept'], 'refused')
        if r['kept'] is None:
            v = r['verdict']
            kept += ': ' + ('not better on the earlier power-ons' if 'other recordings' in v else 'not better on the query' if 'query' in v else v[:60])
        out.append(f"| {r['support']} | {', '.join(j.split('_')[0] + '_' + j.split('_')[1] for j in r['judged_on'])} | {kept} | {carried(r['carry_over']) if r['kept'] or r['carry_over'] else '–'} | {len(r['later_with_rest'])} | {f(r['static_bias'])} | {f(r['power_on_bias'])} | {f(r['deployed'])} | {r['each']} |")
    valid = [r for r in rows if r['later_with_rest']]
    mean = lambda k: statistics.mean(r[k] for r in valid)
    out.append(f"| mean | | {sum(1 for r in rows if r['kept'])} of {len(rows)} kept | | | {f(mean('static_bias'))} | {f(mean('power_on_bias'))} | {f(mean('deployed'))} | |")
    return '\n'.join(out)


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
        ratio = carried(c)
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
    past = {name: past_rows(work, name) for name in ('recorded', 'injected')}
    json.dump({**result, 'judged_on_the_past': past}, open(out_json, 'w'), indent=1)
    md = open(out_md).read()
    for key, tables, render in (('', result, table), ('-past', past, past_table)):
        for name, rows in tables.items():
            tag = f'euroc-adapt-{name}{key}{MARKER_SUFFIX}'
            begin, end = f'<!-- {tag}:begin -->', f'<!-- {tag}:end -->'
            md = re.sub(re.escape(begin) + '.*?' + re.escape(end), lambda _: f'{begin}\n{render(rows)}\n{end}', md, flags=re.S)
    open(out_md, 'w').write(md)


if __name__ == '__main__':
    main()
