# The real firmware for the Arduino Mega 2560, built with Debian's avr-gcc
# against the Arduino AVR core sources (packages gcc-avr, avr-libc,
# binutils-avr, arduino-core-avr; `make firmware-deps` at the top level
# installs them), and the simulated board that runs the binary on simavr
# (packages simavr, libsimavr-dev, libelf-dev, pkg-config). Included by
# hw/Makefile.

AVR_CC      ?= avr-gcc
AVR_CXX     ?= avr-g++
AVR_OBJCOPY ?= avr-objcopy
AVR_SIZE    ?= avr-size
AVRDUDE     ?= avrdude
ARDUINO_AVR ?= /usr/share/arduino/hardware/arduino/avr
MCU         := atmega2560
F_CPU       := 16000000L

FW_BUILD  := firmware/build
FW_ELF    := $(FW_BUILD)/plush_winch.elf
FW_HEX    := $(FW_BUILD)/plush_winch.hex
CORE_DIR  := $(ARDUINO_AVR)/cores/arduino
VARIANT   := $(ARDUINO_AVR)/variants/mega

# Arduino 1.8.7's WString.cpp uses DECIMAL_DIG, which gcc-avr 5.4's
# <float.h> lacks (ArduinoCore-avr#633); 17 digits round-trip a double.
AVR_DEFS  := -mmcu=$(MCU) -DF_CPU=$(F_CPU) -DARDUINO=10807 -DARDUINO_AVR_MEGA2560 -DARDUINO_ARCH_AVR \
             -DDECIMAL_DIG=17
AVR_INC   := -I$(CORE_DIR) -I$(VARIANT)
# The flags of the Arduino IDE's platform.txt, without link-time optimisation.
AVR_COMMON := -Os -g -ffunction-sections -fdata-sections $(AVR_DEFS) $(AVR_INC)
AVR_CFLAGS := $(AVR_COMMON) -std=gnu11 -w
AVR_CXXFLAGS := $(AVR_COMMON) -std=gnu++11 -fpermissive -fno-exceptions -fno-threadsafe-statics -w
# The sketch and the protocol core are ours: full warnings, as on the host.
FW_CXXFLAGS := $(AVR_COMMON) -std=gnu++11 -fno-exceptions -fno-threadsafe-statics -Wall -Wextra

CORE_SRC  := $(wildcard $(CORE_DIR)/*.c $(CORE_DIR)/*.cpp $(CORE_DIR)/*.S)
CORE_OBJ  := $(patsubst $(CORE_DIR)/%,$(FW_BUILD)/core/%.o,$(CORE_SRC))

CHECK_AVR = command -v $(AVR_CXX) >/dev/null 2>&1 && [ -f $(CORE_DIR)/Arduino.h ] || { \
  echo "hw: error: the AVR toolchain ($(AVR_CXX)) or the Arduino AVR core ($(CORE_DIR)) is missing." >&2; \
  echo "hw: install them with 'sudo apt-get install gcc-avr avr-libc binutils-avr arduino-core-avr' or run 'make firmware-deps' at the top level." >&2; \
  exit 1; }

firmware: $(FW_HEX)
	@$(AVR_SIZE) -C --mcu=$(MCU) $(FW_ELF) 2>/dev/null || $(AVR_SIZE) $(FW_ELF)

$(FW_BUILD)/core/%.c.o: $(CORE_DIR)/%.c
	@$(CHECK_AVR)
	@mkdir -p $(dir $@)
	$(AVR_CC) $(AVR_CFLAGS) -c $< -o $@

$(FW_BUILD)/core/%.cpp.o: $(CORE_DIR)/%.cpp
	@$(CHECK_AVR)
	@mkdir -p $(dir $@)
	$(AVR_CXX) $(AVR_CXXFLAGS) -c $< -o $@

$(FW_BUILD)/core/%.S.o: $(CORE_DIR)/%.S
	@$(CHECK_AVR)
	@mkdir -p $(dir $@)
	$(AVR_CC) $(AVR_DEFS) $(AVR_INC) -x assembler-with-cpp -c $< -o $@

$(FW_BUILD)/core.a: $(CORE_OBJ)
	rm -f $@
	avr-ar rcs $@ $^

# The .ino is C++ once Arduino.h is included first (what the IDE does;
# the sketch declares every function before use, so no prototypes are generated).
$(FW_BUILD)/plush_winch.ino.o: $(SKETCH) $(CORE_H)
	@$(CHECK_AVR)
	@mkdir -p $(FW_BUILD)
	$(AVR_CXX) $(FW_CXXFLAGS) -Ifirmware/plush_winch -include Arduino.h -x c++ -c $< -o $@

$(FW_BUILD)/protocol_core.o: $(CORE) $(CORE_H)
	@$(CHECK_AVR)
	@mkdir -p $(FW_BUILD)
	$(AVR_CXX) $(FW_CXXFLAGS) -c $< -o $@

$(FW_ELF): $(FW_BUILD)/plush_winch.ino.o $(FW_BUILD)/protocol_core.o $(FW_BUILD)/core.a
	$(AVR_CC) -Os -g -Wl,--gc-sections -mmcu=$(MCU) -o $@ $(FW_BUILD)/plush_winch.ino.o $(FW_BUILD)/protocol_core.o \
	  $(FW_BUILD)/core.a -lm

$(FW_HEX): $(FW_ELF)
	$(AVR_OBJCOPY) -O ihex -R .eeprom $< $@

# The Mega's stk500v2 bootloader, as the Arduino IDE flashes it.
flash: $(FW_HEX)
	@[ -n "$(PORT)" ] || { echo "hw: error: say which port: make -C hw flash PORT=/dev/ttyACM0" >&2; exit 1; }
	$(AVRDUDE) -p $(MCU) -c wiring -P $(PORT) -b 115200 -D -U flash:w:$(FW_HEX):i

# ------------------------------------------------------- simulated board --

CC        ?= cc
SIM_BUILD := simavr/build
SIM       := $(SIM_BUILD)/plush-board-sim
SIM_CFLAGS := -O2 -g -std=gnu11 -Wall -Wextra

CHECK_SIMAVR = pkg-config --exists simavr libelf 2>/dev/null || { \
  echo "hw: error: simavr's library and headers (with libelf) are missing." >&2; \
  echo "hw: install them with 'sudo apt-get install simavr libsimavr-dev libelf-dev pkg-config' or run 'make firmware-deps' at the top level." >&2; \
  exit 1; }

simavr: $(SIM) $(FW_ELF)

$(SIM): simavr/board_sim.c
	@$(CHECK_SIMAVR)
	@mkdir -p $(SIM_BUILD)
	$(CC) $(SIM_CFLAGS) $$(pkg-config --cflags simavr libelf) -o $@ $< $$(pkg-config --libs --static simavr libelf) -lm
