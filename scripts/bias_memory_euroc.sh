#!/usr/bin/env bash
# The turn-on bias remembered across EuRoC's eleven power-ons of one ADIS16448
# (`imu-fsda bias-memory`, `eval --bias-memory`): each recording scored with the power-on bias
# alone, with the other ten remembered (leave one out), and with only those recorded before
# it (EuRoC's numbering: MH_01 … MH_05, V1_01 … V2_03). Writes the table in docs/poweron.md
# between `<!-- euroc-memory:begin -->` and `<!-- euroc-memory:end -->`.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD=${IMU_FSDA_NO_BUILD:-} bash "$here/scripts/setup.sh"
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
data="${DATA:-$here/../shared/data}"
work="$IMU_FSDA_CACHE/bias-memory-euroc"
rm -rf "$work"; mkdir -p "$work" "$IMU_FSDA_CACHE/bags"
bags=()
for s in MH_01_easy MH_02_easy MH_03_medium MH_04_difficult MH_05_difficult V1_01_easy V1_02_medium V1_03_difficult V2_01_easy V2_02_medium V2_03_difficult; do
  [ -f "$IMU_FSDA_CACHE/bags/$s.mcap" ] || "$bin" import "$data/euroc/$s" -o "$IMU_FSDA_CACHE/bags/$s.mcap" >&2
  bags+=("$IMU_FSDA_CACHE/bags/$s.mcap")
done
"$bin" bias-memory "${bags[@]}" -o "$work/all.json" 2>/dev/null
"$bin" eval "${bags[@]}" --method power-on-bias --json "$work/alone.json" >/dev/null
"$bin" eval "${bags[@]}" --method power-on-bias --bias-memory "$work/all.json" --json "$work/others.json" >/dev/null
for i in "${!bags[@]}"; do
  s="$(basename "${bags[$i]}" .mcap)"
  if [ "$i" -ge 1 ]; then
    "$bin" bias-memory "${bags[@]:0:$i}" -o "$work/before-$s.json" 2>/dev/null
    "$bin" eval "${bags[$i]}" --method power-on-bias --bias-memory "$work/before-$s.json" --json "$work/earlier-$s.json" >/dev/null
  fi
done
"$PYTHON" - "$work" "$here/docs/poweron.md" <<'PY'
import json, os, re, sys
work, md_path = sys.argv[1:3]
rows = lambda f: {r['bag']: r for r in json.load(open(os.path.join(work, f)))['rows'] if r.get('aoe_deg') is not None}
alone, others = rows('alone.json'), rows('others.json')
def before(note):
    m = re.search(r'before the first standstill \[([^\]]*)\] rad/s from (\d+) earlier', note)
    return f"[{m.group(1)}] from {m.group(2)}" if m else ('not predicted' if 'do not predict' in note else '–')
out = ['| recording | power-on bias alone | the other ten remembered | what they predicted (rad/s) | only the earlier ones remembered | what they predicted |',
       '|---|---|---|---|---|---|']
for bag in alone:
    e = os.path.join(work, f'earlier-{bag}.json')
    er = rows(os.path.basename(e)).get(bag) if os.path.exists(e) else None
    out.append(f"| {bag} | {alone[bag]['aoe_deg']:.2f} | {others[bag]['aoe_deg']:.2f} | {before(others[bag]['note'])} | "
               f"{er['aoe_deg']:.2f} | {before(er['note'])} |" if er else
               f"| {bag} | {alone[bag]['aoe_deg']:.2f} | {others[bag]['aoe_deg']:.2f} | {before(others[bag]['note'])} | – (none earlier) | – |")
md = open(md_path).read()
a, b = '<!-- euroc-memory:begin -->', '<!-- euroc-memory:end -->'
md = re.sub(re.escape(a) + '.*?' + re.escape(b), lambda _: a + '\n' + '\n'.join(out) + '\n' + b, md, flags=re.S)
open(md_path, 'w').write(md)
print('\n'.join(out))
PY
