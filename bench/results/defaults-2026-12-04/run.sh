#!/bin/bash
cd /work/main
out=bench/out/defaults2; mkdir -p $out
run() { flock /work/timing.lock ./build/mbvh bench "$2" $3 --backend cpu-scalar,cpu-avx2,cpu-avx512 --layout mbvh2,mbvh4,mbvh8 --traversal stack,bitstack,stack-ordered --query closest,any --kinds primary,diffuse,shadow --count 100000 --passes 5 --csv $out/$1.csv > $out/$1.log 2>&1; }
run bunny ../shared/scenes/bun_zipper.ply.zst ""
run conference ../shared/scenes/conference.obj.zst "--camera 0,300,0,1000,200,0"
run sibenik ../shared/scenes/sibenik.obj.zst "--camera -14,-9,0,10,-6,0"
run sponza ../shared/scenes/sponza_dabrovic.obj.zst "--camera -10,4,0,10,5,0"
run hairball gen:hairball:100000 ""
echo done > $out/DONE
