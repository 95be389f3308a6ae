#!/usr/bin/env bash
# Land a sweep's finished runs on main: collect.sh copies the new ones, they are committed whole, then their
# records leave the tree (kept in that commit, listed in studies/records.json), their configs are migrated to the
# current schema, and that is committed too:
#   bash studies/paper/land.sh <sweep dir> <destination, e.g. studies/paper/runs_5-14> [commit message]
# From main's root. Only the runs new to the destination are added (the older ones stay in their own commits). A
# landing in studies/paper also regenerates the verdict report in the second commit.
set -euo pipefail
SRC=${1:?usage: land.sh <sweep dir> <destination> [message]}
DST=${2:?usage: land.sh <sweep dir> <destination> [message]}
MSG=${3:-"$(basename "$DST"): runs landed"}
DST=$(realpath -m --relative-to=. "$DST")  # ./studies/paper/… or an absolute path reads as studies/paper/…
mkdir -p "$DST"
before=$(find "$DST" -mindepth 1 -maxdepth 1 -type d -printf '%f\n' | sort)
bash "$(dirname "$0")/collect.sh" "$SRC" "$DST" > /dev/null
new=$(comm -13 <(echo "$before") <(find "$DST" -mindepth 1 -maxdepth 1 -type d -printf '%f\n' | sort))
if [ -z "$new" ]; then echo "land.sh: no new finished run in $SRC"; exit 0; fi
for run in $new; do git add -f "$DST/$run"; done
[ -f "$DST/multirun.yaml" ] && git add -f "$DST/multirun.yaml"
git commit -q -m "$MSG: $(echo $new | tr ' ' ',')"
python -m kddrl_trl.devtools.records archive "$DST"
# a run of a pinned older commit: its config as the current schema reads it (main keeps the migrated copy; the
# record in the commit above keeps it as the run wrote it)
python -m kddrl_trl.devtools.migrate_configs "$DST" > /dev/null
git add "$DST"
# the verdict study's report follows the runs it reads (every record of the study restored first); another study's
# landing leaves it as it is. The guide home page's verdict table is a copy of the report's "In short" table
note="the records of $(git rev-parse --short HEAD) leave the tree (studies/records.json)"
case "$DST" in
  studies/paper/*)
    python -m kddrl_trl.devtools.records restore paper > /dev/null
    python -m kddrl_trl.report studies/paper/runs studies/paper/runs_5-14 out=studies/paper \
      claims=studies/paper/claims.yaml title="Verdict report" lcgan_figures=false > /dev/null
    git add studies/paper/report.md studies/paper/report.json studies/paper/fig*.png
    note="$note; report regenerated"
    # a regenerated table can break the guide's tested tables: say so now, not in CI
    python -m pytest -q -p no:cacheprovider tests/test_readme.py > /dev/null \
      || echo "land.sh: tests/test_readme.py fails after this landing; copy the report's \"In short\" table into docs/index.md before you stop" >&2;;
esac
git commit -q -m "$(basename "$DST"): $note"
echo "land.sh: landed $(echo "$new" | wc -l) run(s): $(echo $new)"
