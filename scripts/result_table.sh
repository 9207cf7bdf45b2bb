# Shell helpers, sourced by scripts that print members of two result.json files side by side
# (scripts/demo.sh, research/experiments/sun/run.sh).

# result_field FILE NAME: the first member NAME of a result.json, "-" when absent.
result_field() {
    v=$(sed -n "s/^[[:space:]]*\"$2\":[[:space:]]*\([^,]*\),\{0,1\}$/\1/p" "$1" | head -n 1)
    echo "${v:--}"
}

# result_row LABEL FORMAT NAME DIR_A DIR_B LABEL_WIDTH COLUMN_WIDTH: one line of the table, the
# member from DIR_A/result.json and DIR_B/result.json printed with FORMAT ("-" when absent).
result_row() {
    a=$(result_field "$4/result.json" "$3")
    b=$(result_field "$5/result.json" "$3")
    [ "$a" = - ] || a=$(printf "$2" "$a")
    [ "$b" = - ] || b=$(printf "$2" "$b")
    printf "   %-$6s %$7s %$7s\n" "$1" "$a" "$b"
}
