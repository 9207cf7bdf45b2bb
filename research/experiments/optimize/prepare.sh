# Sourced by run_table.sh and research/experiments/views/run_views_shape.sh: the generated
# inputs of the deformation and shape-from-shadow tasks, made once and kept (the bent mesh,
# bend_obj.py; the fitted and perturbed spheres, perturb_spheres.py), so that both experiments
# start from the same files. Usage: pen_prepare OPTDIR ROOT BIN GEN MESH (MESH spot or bob; GEN
# holds meshes/ and spheres/).
pen_prepare() {
    case $5 in
    spot) _obj=spot_triangulated.obj _along=z _toward=x ;;
    bob) _obj=bob_tri.obj _along=x _toward=z ;;
    *) echo "unknown mesh $5 (expected spot or bob)" >&2 && exit 2 ;;
    esac
    mkdir -p "$4/meshes" "$4/spheres"
    [ -s "$4/meshes/$5_bent.obj" ] ||
        python3 "$1/bend_obj.py" "$2/data/meshes/$_obj" "$4/meshes/$5_bent.obj" \
            --along $_along --toward $_toward --curvature 0.4
    if [ ! -s "$4/spheres/$5_start.json" ]; then
        "$3" fit-spheres "$2/data/meshes/$_obj" -n 32 -o "$4/spheres/$5_fit32.json" > /dev/null
        python3 "$1/perturb_spheres.py" "$4/spheres/$5_fit32.json" \
            "$4/spheres/$5_start.json" --scale 0.75 --shift 0.1 0 -0.12
    fi
}
