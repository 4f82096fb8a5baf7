#!/usr/bin/env bash
# Check the size limits of the house rules (docs/architecture.md), so anyone can rerun
# them:
#   - no file in src/ over 700 lines before its #[cfg(test)] module;
#   - no mod.rs over 150 lines of code (comments, doc comments and blank lines not
#     counted).
# Prints every file over a limit and exits 1 if there is one.
#
#   benches/house_rules.sh
set -euo pipefail
cd "$(dirname "$0")/.."
bad=0
while IFS= read -r f; do
    # Lines before the first `#[cfg(test)]` (the whole file when it has none).
    n=$(awk '/^#\[cfg\(test\)\]/ { exit } { n++ } END { print n + 0 }' "$f")
    if [ "$n" -gt 700 ]; then
        echo "$f: $n lines before its #[cfg(test)] module (limit 700)"
        bad=1
    fi
    if [ "$(basename "$f")" = mod.rs ]; then
        code=$(awk '/^#\[cfg\(test\)\]/ { exit }
                    { t = $0; sub(/^[ \t]+/, "", t) }
                    t == "" || t ~ /^\/\// { next }
                    { n++ } END { print n + 0 }' "$f")
        if [ "$code" -gt 150 ]; then
            echo "$f: $code lines of code (limit 150 for a mod.rs)"
            bad=1
        fi
    fi
done < <(find src -name '*.rs' | sort)
if [ "$bad" = 0 ]; then
    echo "house rules: every src file within 700 lines before its tests, every mod.rs within 150 lines of code"
fi
exit "$bad"
