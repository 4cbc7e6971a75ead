# SPDX-License-Identifier: MIT
# mpi_tests.cmake — the MPI tests (included by CMakeLists.txt when mbvh::mpi is built): each runs
# under FindMPI's mpiexec on this host only (shared memory, loopback), as root where CI runs as
# root, with more ranks than cores allowed, and a TIMEOUT so a hung rank cannot hold CI. Label
# `mpi` (the Release stage's; scripts/test). Without MPI one test says "not built".

# Open MPI's settings for one host (docs/mpi.md): run as root, oversubscribe 2 cores, no network.
set(MBVH_MPI_TEST_ENV
  "OMPI_ALLOW_RUN_AS_ROOT=1" "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1" "OMPI_MCA_rmaps_base_oversubscribe=1"
  "OMPI_MCA_btl=self,vader" "OMPI_MCA_btl_vader_single_copy_mechanism=none"
  "OMPI_MCA_btl_tcp_if_include=lo" "OMPI_MCA_oob_tcp_if_include=lo" "OMPI_MCA_hwloc_base_binding_policy=none"
  "PRTE_MCA_rmaps_default_mapping_policy=:oversubscribe")

# mbvh_mpi_test(NAME RANKS TIMEOUT COMMAND...): COMMAND on RANKS ranks of this host.
function(mbvh_mpi_test name ranks timeout)
  add_test(NAME "mpi: ${name}"
           COMMAND ${MPIEXEC_EXECUTABLE} ${MPIEXEC_NUMPROC_FLAG} ${ranks} ${MPIEXEC_PREFLAGS} ${ARGN} ${MPIEXEC_POSTFLAGS})
  set_tests_properties("mpi: ${name}" PROPERTIES LABELS mpi TIMEOUT ${timeout} ENVIRONMENT "${MBVH_MPI_TEST_ENV}")
endfunction()

# mbvh_mpi_script_test(NAME TIMEOUT SCRIPT ARGS...): a shell script that runs mpiexec itself
# (several runs and their comparisons); it gets MBVH, MBVH_MPI, MPIEXEC and the scenes directory.
function(mbvh_mpi_script_test name timeout script)
  add_test(NAME "mpi: ${name}" COMMAND bash ${PROJECT_SOURCE_DIR}/${script} ${ARGN})
  set_tests_properties("mpi: ${name}" PROPERTIES LABELS mpi TIMEOUT ${timeout}
    ENVIRONMENT "${MBVH_MPI_TEST_ENV};MBVH=$<TARGET_FILE:mbvh-cli>;MBVH_MPI=$<TARGET_FILE:mbvh-mpi>;MPIEXEC=${MPIEXEC_EXECUTABLE};MBVH_SCENES_DIR=${MBVH_SCENES_DIR}")
endfunction()

# -- the tests (the data-parallel ones below them)
mbvh_mpi_script_test("replicated, 2 ranks: trace and render cmp-equal to one process; an error on a rank" 300
                     tests/mpi/replicated.sh 2)
mbvh_mpi_script_test("replicated, 3 ranks: trace and render cmp-equal to one process; an error on a rank" 300
                     tests/mpi/replicated.sh 3)
# the plain program never links libmpi (its dynamic dependencies, captured before they are searched)
add_test(NAME "mpi: mbvh links no libmpi"
         COMMAND bash -c "deps=\"$(ldd \"$1\")\" && echo \"$deps\" | grep -c . && ! grep -qi libmpi <<<\"$deps\"" _ $<TARGET_FILE:mbvh-cli>)
set_tests_properties("mpi: mbvh links no libmpi" PROPERTIES LABELS mpi TIMEOUT 30)
mbvh_mpi_script_test("data-parallel, 2 ranks: check, trace and a render under a per-rank budget against one process" 300
                     tests/mpi/data.sh 2)
mbvh_mpi_script_test("data-parallel, 3 ranks: check, trace and a render under a per-rank budget against one process" 300
                     tests/mpi/data.sh 3)
if(TARGET mbvh-example-mpi)
  mbvh_mpi_test("examples/mpi_trace.cpp on 3 ranks: bit for bit one process" 3 120 $<TARGET_FILE:mbvh-example-mpi>)
endif()
# the data-parallel mode (tests/mpi/test_data_parallel.cpp): partition, trace_data_parallel against
# one process's cpu-scalar, load_scene_part's memory share; on 2 and 3 ranks (more ranks than cores)
add_executable(mbvh-mpi-tests tests/mpi/test_data_parallel.cpp)
target_compile_options(mbvh-mpi-tests PRIVATE ${MBVH_WARNINGS})
target_link_libraries(mbvh-mpi-tests PRIVATE mbvh_mpi mbvh_tools mbvh)
target_compile_definitions(mbvh-mpi-tests PRIVATE MBVH_SCENES_DIR="${MBVH_SCENES_DIR}" MBVH_CLI_PATH="$<TARGET_FILE:mbvh-cli>")
mbvh_mpi_test("data-parallel on 2 ranks" 2 120 $<TARGET_FILE:mbvh-mpi-tests>)
mbvh_mpi_test("data-parallel on 3 ranks" 3 120 $<TARGET_FILE:mbvh-mpi-tests>)
