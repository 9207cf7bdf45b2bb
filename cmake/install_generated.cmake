# Run by `cmake --install` (install(CODE) in CMakeLists.txt, "Install"): writes the two files
# that must name the prefix the tree is installed into, which is known only now
# (`cmake --install build --prefix DIR` overrides CMAKE_INSTALL_PREFIX of the configure step).
# DESTDIR stages the files without changing the paths written into them.
# In: CMAKE_INSTALL_PREFIX, PEN_SOURCE_DIR, PEN_LIBDIR, PEN_INCLUDEDIR, PEN_PYTHONDIR, PEN_SONAME,
#     PEN_PC_VERSION, PEN_PC_REQUIRES_PRIVATE, PEN_PC_LIBS_PRIVATE.
# PEN_FULL_<dir>: the absolute path; PEN_PC_<dir>: the same as penumbra.pc writes it.
set(PEN_PC_PREFIX "${CMAKE_INSTALL_PREFIX}")
foreach(dir LIBDIR INCLUDEDIR PYTHONDIR)
  if(IS_ABSOLUTE "${PEN_${dir}}")
    set(PEN_FULL_${dir} "${PEN_${dir}}")
    set(PEN_PC_${dir} "${PEN_${dir}}")
  else()
    set(PEN_FULL_${dir} "${CMAKE_INSTALL_PREFIX}/${PEN_${dir}}")
    set(PEN_PC_${dir} "\${prefix}/${PEN_${dir}}")
  endif()
endforeach()

# penumbra.pc
set(pc "$ENV{DESTDIR}${PEN_FULL_LIBDIR}/pkgconfig/penumbra.pc")
message(STATUS "Installing: ${pc}")
configure_file("${PEN_SOURCE_DIR}/cmake/penumbra.pc.in" "${pc}" @ONLY)
list(APPEND CMAKE_INSTALL_MANIFEST_FILES "${pc}") # listed in install_manifest.txt like the rest

# penumbra/_libpath.py: the Python package loads this library (python/penumbra/_lib.py) with no
# environment variable.
set(py "$ENV{DESTDIR}${PEN_FULL_PYTHONDIR}/penumbra/_libpath.py")
message(STATUS "Installing: ${py}")
file(WRITE "${py}"
  "\"\"\"Written by cmake --install: the libpenumbra installed with this package.\"\"\"\n\n"
  "LIBRARY = \"${PEN_FULL_LIBDIR}/${PEN_SONAME}\"\n")
list(APPEND CMAKE_INSTALL_MANIFEST_FILES "${py}")
